# tests/shims/libgpiod2.cmake - the real libgpiod 2 (soname libgpiod.so.3) for the GPIO tests,
# built into this build tree: Debian 12 packages only libgpiod 1 (libgpiod2, libgpiod.so.2),
# and Debian 13's libgpiod3 is built against a newer glibc. Test-only: the shims never link it.
# Sets MBFB_LIBGPIOD2 (the library's path, empty when there is none; cached, for tests/kernel too)
# and MBFB_LIBGPIOD2_REASON.
#
# Its source, the first that applies:
#   1. LIBGPIOD2_SOURCE_DIR: a libgpiod 2 source tree (a release, a clone, or an unpacked
#      `gpiod` sdist): lib/*.c and include/gpiod.h; copied from, never written to.
#   2. PyPI's `gpiod` (libgpiod's own Python bindings) sdist, which vendors libgpiod's C
#      library: fetched once with the venv's pip at the version and hash pinned below, unless
#      MBFB_FETCH_LIBGPIOD2 is OFF.
# Environment or -D, the environment winning (as tools/matiec/matiec.cmake).

# gpiod 2.3.0 vendors libgpiod 2.2.1 (its libgpiod-version.txt)
set(MBFB_GPIOD_SDIST_VERSION "2.3.0")
set(MBFB_GPIOD_SDIST_SHA256 "daa840ed5b691e7078a9cf21c79fe813b9a91c3ed0bdbafae0181c7b98b80300")

_mbfb_setting(LIBGPIOD2_SOURCE_DIR "" "A libgpiod 2 source tree (lib/, include/gpiod.h)")
_mbfb_setting(MBFB_FETCH_LIBGPIOD2 "ON" "Fetch libgpiod 2's source (PyPI gpiod sdist) for the GPIO tests")

set(MBFB_LIBGPIOD2 "")
set(MBFB_LIBGPIOD2_REASON "")
set(_top "${CMAKE_BINARY_DIR}/_libgpiod2")
set(_src "")
if(NOT LIBGPIOD2_SOURCE_DIR STREQUAL "")
  set(_src "${LIBGPIOD2_SOURCE_DIR}")
  set(_from "LIBGPIOD2_SOURCE_DIR=${LIBGPIOD2_SOURCE_DIR}")
elseif(MBFB_FETCH_LIBGPIOD2)
  set(_src "${_top}/gpiod-${MBFB_GPIOD_SDIST_VERSION}")
  set(_from "PyPI gpiod==${MBFB_GPIOD_SDIST_VERSION} (sdist, sha256 pinned)")
  if(NOT EXISTS "${_src}/include/gpiod.h")
    file(MAKE_DIRECTORY "${_top}")
    file(WRITE "${_top}/requirements.txt"
         "gpiod==${MBFB_GPIOD_SDIST_VERSION} --hash=sha256:${MBFB_GPIOD_SDIST_SHA256}\n")
    set(_tar "${_top}/gpiod-${MBFB_GPIOD_SDIST_VERSION}.tar.gz")
    if(NOT EXISTS "${_tar}")
      message(STATUS "libgpiod2: fetching ${_from}")
      execute_process(COMMAND "${MBFB_PYTHON}" -m pip download --quiet --no-deps
                              --no-binary gpiod --require-hashes -r "${_top}/requirements.txt"
                              -d "${_top}"
                      RESULT_VARIABLE _rc OUTPUT_QUIET ERROR_VARIABLE _err)
      if(NOT _rc EQUAL 0)
        # pip's last line, fit for a test's environment (no list separators)
        string(STRIP "${_err}" _err)
        string(REGEX REPLACE ".*\n" "" _err "${_err}")
        string(REPLACE ";" "," _err "${_err}")
        set(MBFB_LIBGPIOD2_REASON "fetching ${_from} failed: ${_err}")
      endif()
    endif()
    if(EXISTS "${_tar}")
      execute_process(COMMAND ${CMAKE_COMMAND} -E tar xzf "${_tar}" WORKING_DIRECTORY "${_top}")
    endif()
  endif()
else()
  set(MBFB_LIBGPIOD2_REASON "no libgpiod 2 source: LIBGPIOD2_SOURCE_DIR unset and MBFB_FETCH_LIBGPIOD2 is OFF")
endif()

if(MBFB_LIBGPIOD2_REASON STREQUAL "" AND NOT EXISTS "${_src}/include/gpiod.h")
  set(MBFB_LIBGPIOD2_REASON "no include/gpiod.h in ${_src} (${_from})")
endif()
if(MBFB_LIBGPIOD2_REASON STREQUAL "")
  file(GLOB _lib_c "${_src}/lib/*.c")
  set(_version "2 (${_from})")
  if(EXISTS "${_src}/libgpiod-version.txt")
    file(STRINGS "${_src}/libgpiod-version.txt" _version LIMIT_COUNT 1)
  endif()
  add_library(mbfb_libgpiod2 SHARED ${_lib_c})
  target_include_directories(mbfb_libgpiod2 PRIVATE "${_src}/include" "${_src}/lib")
  target_compile_definitions(mbfb_libgpiod2 PRIVATE _GNU_SOURCE GPIOD_VERSION_STR="${_version}")
  target_compile_options(mbfb_libgpiod2 PRIVATE -fvisibility=hidden -w)
  set_target_properties(mbfb_libgpiod2 PROPERTIES OUTPUT_NAME gpiod VERSION 3 SOVERSION 3
                        LIBRARY_OUTPUT_DIRECTORY "${CMAKE_CURRENT_BINARY_DIR}/libgpiod2")
  set(MBFB_LIBGPIOD2 "${CMAKE_CURRENT_BINARY_DIR}/libgpiod2/libgpiod.so.3")
  set(MBFB_LIBGPIOD2 "${MBFB_LIBGPIOD2}" CACHE INTERNAL "libgpiod 2 built for the tests")
  message(STATUS "libgpiod2: libgpiod ${_version} from ${_from} (target mbfb_libgpiod2)")
else()
  set(MBFB_LIBGPIOD2 "" CACHE INTERNAL "libgpiod 2 built for the tests")
  message(STATUS "libgpiod2: none: ${MBFB_LIBGPIOD2_REASON}")
endif()

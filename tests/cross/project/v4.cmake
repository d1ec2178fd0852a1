# The v4 package for one ARM target (tests/cross/project), as Runtime v4 builds a program with
# it: the library folder (MBFB_V4_PACKAGE: library.properties + src/) compiled as
# libraries.mk does (src/*.c as C with the library's defines: our shims with -Werror, the
# bundled libmodbus with -Wall), and the library's ST compiled to C++ by STruC++
# (MBFB_V4_GEN/mbfb_v4.cpp, with STruC++'s runtime headers MBFB_STRUCPP_INC, C++17, as
# v4/CMakeLists.txt's mbfb_v4_check), linked into one shared library with no undefined symbol.
file(GLOB _v4_c ${MBFB_V4_PACKAGE}/src/*.c)
file(GLOB _v4_ours ${MBFB_V4_PACKAGE}/src/mbfb_*.c)
file(STRINGS ${MBFB_V4_PACKAGE}/library.properties _defs REGEX "^defines=")
string(REGEX REPLACE "^defines=" "" _defs "${_defs}")
string(REPLACE "," ";" _defs "${_defs}")
add_library(mbfb_v4_package SHARED ${_v4_c} ${MBFB_V4_GEN}/mbfb_v4.cpp)
target_include_directories(mbfb_v4_package PRIVATE ${MBFB_V4_PACKAGE}/src ${MBFB_V4_GEN}
                           ${MBFB_STRUCPP_INC})
target_compile_definitions(mbfb_v4_package PRIVATE ${_defs})
target_compile_options(mbfb_v4_package PRIVATE -O1 -Wall -Wno-unknown-pragmas
                       -Wno-deprecated-declarations)
set_source_files_properties(${_v4_ours} PROPERTIES COMPILE_OPTIONS "-Wextra;-Werror")
set_source_files_properties(${MBFB_V4_GEN}/mbfb_v4.cpp PROPERTIES COMPILE_OPTIONS
                            "-include;mbfb_strucpp.hpp;-DSTRUCPP_THREADED;-fno-gnu-unique")
set_target_properties(mbfb_v4_package PROPERTIES CXX_STANDARD 17 CXX_STANDARD_REQUIRED ON)
target_link_libraries(mbfb_v4_package PRIVATE Threads::Threads)
target_link_options(mbfb_v4_package PRIVATE -Wl,--no-undefined)

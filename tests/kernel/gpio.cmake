# GPIO direction on a kernel GPIO chip (test_gpio.py): the kernel's gpio-sim in the test bed's
# guest (built for its kernel by gpio_sim.sh), the shims through the real libgpiod 1 and 2.
# Alone in a parallel run, like the other kernel tests (a TCG guest takes a whole core).
# Included by tests/CMakeLists.txt where the bed is. The shims flavour of the bed's own
# programs: Debian's libmodbus (the guest gets the host's, as `ldd` names it).
if("lm_debian" IN_LIST MBFB_FLAVOURS)
  set(_kgflavour lm_debian)
else()
  set(_kgflavour default)
endif()
add_executable(kernel_guest_gpio ${CMAKE_CURRENT_LIST_DIR}/guest_gpio.c)
target_link_libraries(kernel_guest_gpio PRIVATE mbfb_${_kgflavour})
target_compile_options(kernel_guest_gpio PRIVATE -Wall -Wextra -Werror)
mbfb_set_rpath(kernel_guest_gpio ${_kgflavour})
# MBFB_LIBGPIOD1 / MBFB_LIBGPIOD2: tests/shims/CMakeLists.txt (an empty one skips with the reason)
add_test(NAME kernel_gpio
         COMMAND ${MBFB_PYTHON} ${CMAKE_CURRENT_LIST_DIR}/test_gpio.py ${CMAKE_BINARY_DIR}
                 $<TARGET_FILE:kernel_guest_gpio> "${MBFB_LIBGPIOD1}" "${MBFB_LIBGPIOD2}")
set_tests_properties(kernel_gpio PROPERTIES LABELS kernel TIMEOUT 170
                     SKIP_RETURN_CODE ${MBFB_SKIP_CODE} RUN_SERIAL TRUE)

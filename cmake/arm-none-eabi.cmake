# CMake toolchain file: bare-metal Cortex-M4F with Debian's arm-none-eabi GCC and newlib
# (packages gcc-arm-none-eabi, libnewlib-arm-none-eabi, libstdc++-arm-none-eabi-newlib).
#   cmake -S . -B build/mcu -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake -DESKIN_DEVICE=ON
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR arm)

find_program(ESKIN_ARM_GCC arm-none-eabi-gcc REQUIRED)
find_program(ESKIN_ARM_GXX arm-none-eabi-g++ REQUIRED)
set(CMAKE_C_COMPILER ${ESKIN_ARM_GCC})
set(CMAKE_CXX_COMPILER ${ESKIN_ARM_GXX})
set(CMAKE_ASM_COMPILER ${ESKIN_ARM_GCC})
# No host executable can run: test the compilers by building a static library.
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)

# The processor: Cortex-M4 with its single-precision FPU, hard-float calling convention.
set(ESKIN_MCU_FLAGS "-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard")
set(CMAKE_C_FLAGS_INIT "${ESKIN_MCU_FLAGS}")
set(CMAKE_CXX_FLAGS_INIT "${ESKIN_MCU_FLAGS}")
set(CMAKE_ASM_FLAGS_INIT "${ESKIN_MCU_FLAGS}")
set(CMAKE_EXE_LINKER_FLAGS_INIT "${ESKIN_MCU_FLAGS}")

set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

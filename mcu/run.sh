#!/usr/bin/env bash
# Run a bare-metal Cortex-M4 program on QEMU's Arm MPS2 board (AN386 image: Cortex-M4F at
# 25 MHz), output through semihosting. -icount shift=0 makes every instruction take 1 ns of
# virtual time, so the board's SysTick (processor clock, 25 MHz) advances one tick per 40
# instructions: the program's tick counts are instruction counts (see docs/mcu.md).
#   mcu/run.sh program.elf [timeout_s]
set -euo pipefail
elf="$1"
limit="${2:-600}"
exec timeout "$limit" qemu-system-arm -M mps2-an386 -cpu cortex-m4 -nographic -monitor none \
  -serial none -semihosting-config enable=on,target=native -icount shift=0 -kernel "$elf"

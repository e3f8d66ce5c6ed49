"""The stack a device program's decision needs, from its linked image (docs/mcu.md, "The stack").

    python tools/mcu_stack.py build/mcu/mcu/eskin-mcu.elf [--write]

Every function's frame is read from its Thumb-2 code (``arm-none-eabi-objdump -d``): the bytes
its ``push``/``stmdb sp!``/``vpush`` instructions save and its ``sub sp, #N`` reserves, all of
them added up (a function that saves on two paths is counted as saving on both: never less than
it uses). A frame that moves the stack pointer by a register (``alloca``, a variable-length
array) has no static size: the check fails. The decision's need is the deepest chain of frames
from ``StreamClassifier::push`` or ``flush`` through the direct calls (``bl``, and ``b`` tail
calls, counted as nested); the classifier's indirect calls (the overlap kernels it picks at
construction, ``INDIRECT_TARGETS``) are counted as the deepest of those kernels; a cycle
(recursion) on the path fails the check. An interrupt may come at the deepest point: each
interrupt handler of the image (``*_Handler`` but the reset and fault handlers, which end the
program) adds the processor's exception frame with the FPU's context (26 words, 8-byte aligned:
``EXCEPTION_FRAME`` bytes) and its own deepest chain, all of them as if nested. Every frame is
the code's own: the model's shapes change how often a loop runs, never a frame, so the need is
one figure per build.

The stack's guard (``MCU_STACK_GUARD_BYTES`` of mcu/mcu_board.h, the lowest bytes of the stack,
no access) must be at least the largest frame of the whole image: a frame larger than the guard
could step over it and write into the heap below without touching it.

``--write`` stores the figure in the image (the word ``mcu_decision_stack_need`` of
``mcu/startup.c``, in flash), where the test program reads it before it constructs the
classifier: a stack that cannot hold the decision beside its caller is refused there. An image
the figure was not written into refuses every model.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

ROOTS = ("_ZN5eskin16StreamClassifier4pushEPKs", "_ZN5eskin16StreamClassifier5flushEv")
#: what the classifier's indirect calls may reach: the overlap kernels (cpp/src/model_overlap.cpp)
INDIRECT_TARGETS = re.compile(r"overlap_f(32|64)_")
#: the exception frame with the FPU context (ARMv7-M: 8 + 18 words, and 4 bytes of alignment)
EXCEPTION_FRAME = 108
#: handlers that end the program (they run on a fresh stack or never return)
TERMINAL_HANDLERS = {"Reset_Handler", "NMI_Handler", "HardFault_Handler", "MemManage_Handler",
                     "BusFault_Handler", "UsageFault_Handler"}
#: the word of mcu/startup.c that --write fills (0: not written)
NEED_SYMBOL = "mcu_decision_stack_need"

FUNC = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
CALL = re.compile(r"\s(bl|blx|b|b\.w|b\.n|beq\.w|bne\.w)\s+[0-9a-f]+ <([^>+]+)>")
INDIRECT = re.compile(r"\s(blx|bx)\s+r\d+\b")
PUSH = re.compile(r"\s(push(?:\.w)?|stmdb(?:\.w)?\s+sp!,)\s*\{([^}]*)\}")
VPUSH = re.compile(r"\svpush\s*\{([^}]*)\}")
SUB_SP = re.compile(r"\ssub(?:\.w|w)?\s+sp,\s*(?:sp,\s*)?#(\d+)")
DYNAMIC = re.compile(r"\s(sub(?:\.w)?\s+sp,\s*(?:sp,\s*)?r\d+|mov(?:\.w)?\s+sp,\s*r\d+)")


def _count_regs(text: str, size: int) -> int:
    n = 0
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"([rsd])(\d+)-[rsd](\d+)", part)
        if m:
            n += int(m.group(3)) - int(m.group(2)) + 1
        elif part:
            n += 1
    return n * size


@dataclass
class Image:
    """Frames (bytes), direct calls and indirect-call sites of every function of an image."""

    frames: dict[str, int] = field(default_factory=dict)
    calls: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))
    indirect: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    dynamic: set[str] = field(default_factory=set)


def read_image(elf: str | Path) -> Image:
    """The frames and calls of a linked image (``arm-none-eabi-objdump -d``)."""
    return parse_disassembly(subprocess.run(
        ["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)],
        check=True, capture_output=True, text=True,
    ).stdout)


def parse_disassembly(out: str) -> Image:
    """The frames and calls of the functions of an ``objdump -d --no-show-raw-insn`` text."""
    img = Image()
    cur = None
    for line in out.splitlines():
        m = FUNC.match(line)
        if m:
            cur = m.group(2)
            img.frames.setdefault(cur, 0)
            continue
        if cur is None or not line.startswith(" "):
            continue
        if DYNAMIC.search(line):
            img.dynamic.add(cur)
        p = PUSH.search(line)
        if p:
            img.frames[cur] += _count_regs(p.group(2), 4)
        v = VPUSH.search(line)
        if v:
            img.frames[cur] += _count_regs(v.group(1), 8 if "d" in v.group(1) else 4)
        s = SUB_SP.search(line)
        if s:
            img.frames[cur] += int(s.group(1))
        c = CALL.search(line)
        if c and c.group(2) != cur:
            img.calls[cur].add(c.group(2))
        elif INDIRECT.search(line) and not re.search(r"\sbx\s+lr\b", line):
            img.indirect[cur] += 1
    return img


class StackError(Exception):
    pass


def deepest(img: Image, roots=ROOTS) -> tuple[int, list[str]]:
    """The largest sum of frames along a call chain from any of ``roots``, and that chain."""
    kernels = sorted(f for f in img.frames if INDIRECT_TARGETS.search(f))
    memo: dict[str, tuple[int, list[str]]] = {}
    active: list[str] = []

    def walk(f: str) -> tuple[int, list[str]]:
        if f in memo:
            return memo[f]
        if f in active:
            raise StackError("recursion on the decision path: " + " -> ".join(active + [f]))
        if f in img.dynamic:
            raise StackError(f"{f} moves the stack pointer by a register (alloca or a "
                             "variable-length array): its frame has no static size")
        active.append(f)
        callees = set(img.calls.get(f, ()))
        if img.indirect.get(f):
            if not kernels:
                raise StackError(f"{f} makes an indirect call and no overlap kernel is known")
            callees |= set(kernels)
        best = (0, [])
        for g in sorted(callees):
            if g not in img.frames:
                continue
            d, path = walk(g)
            if d > best[0]:
                best = (d, path)
        active.pop()
        memo[f] = (img.frames[f] + best[0], [f] + best[1])
        return memo[f]

    results = [walk(r) for r in roots if r in img.frames]
    if not results:
        raise StackError(f"none of {', '.join(roots)} in the image")
    return max(results, key=lambda t: t[0])


def decision_need(img: Image) -> tuple[int, list[str], int]:
    """(the decision's need with the interrupts', the decision's chain, the interrupts' part)."""
    need, path = deepest(img)
    irq = 0
    for h in sorted(f for f in img.frames if f.endswith("_Handler") or f.endswith("IRQHandler")):
        if h not in TERMINAL_HANDLERS:
            irq += EXCEPTION_FRAME + deepest(img, (h,))[0]
    return need + irq, path, irq


def guard_bytes() -> int:
    text = (Path(__file__).resolve().parents[1] / "mcu" / "mcu_board.h").read_text()
    return int(re.search(r"#define MCU_STACK_GUARD_BYTES (\d+)u", text).group(1))


def check_guard(img: Image) -> tuple[int, str]:
    """(the largest frame of the image, its function); fails when it exceeds the guard."""
    f = max(img.frames, key=img.frames.get)
    if img.frames[f] > guard_bytes():
        raise StackError(f"{f} has a {img.frames[f]}-byte frame, more than the stack's "
                         f"{guard_bytes()}-byte guard: it could step over it")
    return img.frames[f], f


def _symbol(elf: str | Path, name: str) -> int | None:
    out = subprocess.run(["arm-none-eabi-nm", str(elf)], check=True, capture_output=True,
                         text=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16)
    return None


def write_need(elf: str | Path, need: int) -> None:
    """Store ``need`` in the image's word NEED_SYMBOL (in flash: the file offset of its
    section plus its place in it)."""
    addr = _symbol(elf, NEED_SYMBOL)
    if addr is None:
        raise StackError(f"{elf} has no {NEED_SYMBOL} (mcu/startup.c)")
    out = subprocess.run(["arm-none-eabi-readelf", "-S", "-W", str(elf)], check=True,
                         capture_output=True, text=True).stdout
    for line in out.splitlines():
        m = re.match(r"\s*\[\s*\d+\]\s+(\S+)\s+(\S+)\s+([0-9a-f]+)\s+([0-9a-f]+)\s+([0-9a-f]+)",
                     line)
        if not m or m.group(2) in ("NULL", "NOBITS"):
            continue
        start, off, size = int(m.group(3), 16), int(m.group(4), 16), int(m.group(5), 16)
        if start <= addr and addr + 4 <= start + size:
            with open(elf, "r+b") as fh:
                fh.seek(off + addr - start)
                fh.write(int(need).to_bytes(4, "little"))
            return
    raise StackError(f"{NEED_SYMBOL} at 0x{addr:x} is in no section of {elf}")


def main(argv: list[str]) -> int:
    args = [a for a in argv if not a.startswith("--")]
    if len(args) != 1:
        print(__doc__)
        return 2
    elf = args[0]
    try:
        img = read_image(elf)
        need, path, irq = decision_need(img)
        largest, where = check_guard(img)
        if "--write" in argv:
            write_need(elf, need)
    except StackError as exc:
        print(f"FAIL: {exc}")
        return 1
    print(f"ok: a decision needs at most {need} bytes of stack: {need - irq} for its deepest chain "
          f"of static frames ({' -> '.join(path)}) and {irq} for the interrupts; the largest "
          f"frame, {largest} bytes ({where}), within the {guard_bytes()}-byte guard"
          + (f"; written into {elf}" if "--write" in argv else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

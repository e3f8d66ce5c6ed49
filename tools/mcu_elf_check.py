"""Check the device build's program for what the controller path must not contain.

    python tools/mcu_elf_check.py build/mcu/mcu/eskin-mcu.elf

1. No exception machinery, RTTI or threads anywhere in the program: none of the symbols of the
   C++ exception runtime (``__cxa_throw``, ``__cxa_begin_catch``, ``__gxx_personality_v0``, the
   ``_Unwind_*`` unwinder), no ``typeinfo`` object, nothing from ``std::thread``/pthreads.
2. No heap allocation on the decision path: the static call graph (direct ``bl``/``b`` calls, read
   from ``arm-none-eabi-objdump -d``) from ``eskin::StreamClassifier::push`` and ``flush`` reaches
   neither ``malloc`` nor ``operator new`` (nor ``free``/``realloc``). The classifier's indirect
   calls (the overlap kernels chosen at construction) are listed: they are leaf functions.
3. The stack (tools/mcu_stack.py): every frame of the program has a static size no larger than
   the stack's guard, and the decision's deepest chain of frames (with the interrupts') has no
   recursion; its size is printed.

Prints one line per check and exits 1 if one fails.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

FORBIDDEN = (
    "__cxa_throw",
    "__cxa_begin_catch",
    "__cxa_allocate_exception",
    "__gxx_personality_v0",
    "_Unwind_RaiseException",
    "_Unwind_Resume",
    "pthread_create",
    "pthread_mutex_lock",
    "_ZTI",
    "_ZNSt6thread",
)
ALLOCATORS = (
    "malloc",
    "_malloc_r",
    "__wrap_malloc",
    "__real_malloc",
    "_Znwj",
    "_Znaj",
    "realloc",
    "_realloc_r",
    "free",
    "_free_r",
    "_ZdlPv",
    "_ZdlPvj",
    "_ZdaPv",
)
ROOTS = ("_ZN5eskin16StreamClassifier4pushEPKs", "_ZN5eskin16StreamClassifier5flushEv")

FUNC = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
CALL = re.compile(r"\s(bl|blx|b|b\.w|b\.n|beq\.w|bne\.w)\s+[0-9a-f]+ <([^>+]+)>")
INDIRECT = re.compile(r"\sblx\s+r\d+")


def call_graph(elf: str) -> tuple[dict[str, set[str]], dict[str, int]]:
    out = subprocess.run(
        ["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", elf],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    graph: dict[str, set[str]] = defaultdict(set)
    indirect: dict[str, int] = defaultdict(int)
    cur = None
    for line in out.splitlines():
        m = FUNC.match(line)
        if m:
            cur = m.group(2)
            continue
        if cur is None:
            continue
        c = CALL.search(line)
        if c and c.group(2) != cur:
            graph[cur].add(c.group(2))
        elif INDIRECT.search(line):
            indirect[cur] += 1
    return graph, indirect


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__)
        return 2
    elf = argv[0]
    syms = subprocess.run(
        ["arm-none-eabi-nm", elf], check=True, capture_output=True, text=True
    ).stdout.split()
    bad = sorted({s for s in syms if any(s.startswith(f) for f in FORBIDDEN)})
    ok = True
    if bad:
        ok = False
        print(f"FAIL: exception/RTTI/thread symbols in {elf}: {', '.join(bad[:10])}")
    else:
        print(f"ok: no exception runtime, RTTI or thread symbols in {elf}")
    graph, indirect = call_graph(elf)
    missing = [r for r in ROOTS if r not in graph]
    if missing:
        print(f"FAIL: {', '.join(missing)} not found in {elf}")
        return 1
    seen: dict[str, str] = {}
    todo = list(ROOTS)
    for r in ROOTS:
        seen[r] = ""
    while todo:
        f = todo.pop()
        for g in graph.get(f, ()):
            if g not in seen:
                seen[g] = f
                todo.append(g)
    hits = [a for a in ALLOCATORS if a in seen]
    if hits:
        ok = False
        chain = [hits[0]]
        while seen[chain[-1]]:
            chain.append(seen[chain[-1]])
        print(f"FAIL: the decision path calls {hits[0]}: " + " <- ".join(chain))
    else:
        ind = sorted(f for f in seen if indirect.get(f))
        print(
            f"ok: no allocation reachable from StreamClassifier::push/flush ({len(seen)} "
            f"functions; indirect calls only in {', '.join(ind) or 'none'})"
        )
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import mcu_stack

    try:
        img = mcu_stack.read_image(elf)
        need, path, irq = mcu_stack.decision_need(img)
        largest, where = mcu_stack.check_guard(img)
        print(f"ok: a decision needs at most {need} bytes of stack ({irq} of them for the "
              f"interrupts); the largest frame, {largest} bytes, is within the "
              f"{mcu_stack.guard_bytes()}-byte guard")
    except mcu_stack.StackError as exc:
        ok = False
        print(f"FAIL: {exc}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

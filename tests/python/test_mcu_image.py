"""The linked device program (docs/mcu.md, "The stack" and "Models that fit"): its stack
(tools/mcu_stack.py's bound from the image's frames and, on QEMU's mps2-an386, the rule at
construction: a caller leaving less stack than a decision needs is refused; the guard: an
overrun ends the run with exit status 5, never silently; the high-water mark on the MCU line),
and its size against the figures the package ships for eskin.deploy.device_budget
(tools/mcu_image_size.py). The image legs are skipped only when qemu-system-arm is not
installed; they cross-build into build/mcu-stack-test."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = next(p for p in Path(__file__).resolve().parents if (p / "README.md").is_file())


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    sys.modules[name] = mod  # its dataclass looks its module up
    spec.loader.exec_module(mod)
    return mod


ms = _tool("mcu_stack")
size_tool = _tool("mcu_image_size")
PUSH = "_ZN5eskin16StreamClassifier4pushEPKs"
FLUSH = "_ZN5eskin16StreamClassifier5flushEv"


def dis(functions: dict[str, list[str]]) -> str:
    """An objdump -d text of the given functions (instructions as objdump prints them)."""
    out, addr = [], 0x1000
    for name, body in functions.items():
        out.append(f"{addr:08x} <{name}>:")
        for ins in body:
            addr += 4
            out.append(f"    {addr:x}:\t{ins}")
        out.append("")
    return "\n".join(out)


def test_frames_are_read_from_the_prologues():
    img = ms.parse_disassembly(dis({
        "a": ["push\t{r4, r5, r6, lr}", "vpush\t{d8-d9}", "sub\tsp, #20", "bx\tlr"],
        "b": ["stmdb\tsp!, {r4, r5, r6, r7, r8, r9, sl, fp, lr}", "subw\tsp, sp, #1268"],
        "c": ["push\t{r3, lr}", "vpush\t{s16-s19}", "sub.w\tsp, sp, #876"],
    }))
    assert img.frames == {"a": 16 + 16 + 20, "b": 36 + 1268, "c": 8 + 16 + 876}


def test_the_need_is_the_deepest_chain_with_the_interrupts():
    img = ms.parse_disassembly(dis({
        PUSH: ["push\t{r4, lr}", "bl\t2000 <shallow>", "bl\t3000 <deep>"],
        FLUSH: ["push\t{r4, lr}", "b.w\t2000 <shallow>"],
        "shallow": ["sub\tsp, #100", "bx\tlr"],
        "deep": ["push\t{r4, r5, r6, lr}", "sub\tsp, #200", "blx\tr3"],
        "overlap_f32_tiled": ["push\t{r4, r5}", "sub\tsp, #40"],
        "overlap_f32_generic": ["push\t{r4}"],
        "SysTick_Handler": ["push\t{r3, lr}"],
        "HardFault_Handler": ["sub\tsp, #500"],  # ends the program: not counted
    }))
    need, path, irq = ms.decision_need(img)
    # push 8 + deep 216 + the larger overlap kernel (indirect call) 48
    assert path == [PUSH, "deep", "overlap_f32_tiled"]
    assert irq == ms.EXCEPTION_FRAME + 8
    assert need == 8 + 216 + 48 + irq


def test_recursion_a_dynamic_frame_and_a_frame_over_the_guard_are_refused():
    rec = ms.parse_disassembly(dis({PUSH: ["push\t{lr}", "bl\t2 <f>"], "f": ["bl\t3 <g>"],
                                    "g": ["push\t{lr}", "bl\t2 <f>"]}))
    with pytest.raises(ms.StackError, match="recursion on the decision path"):
        ms.decision_need(rec)
    vla = ms.parse_disassembly(dis({PUSH: ["push\t{r7, lr}", "sub\tsp, sp, r3"]}))
    with pytest.raises(ms.StackError, match="no static size"):
        ms.decision_need(vla)
    guard = ms.guard_bytes()
    ok = ms.parse_disassembly(dis({"f": [f"sub.w\tsp, sp, #{guard}"]}))
    assert ms.check_guard(ok) == (guard, "f")
    big = ms.parse_disassembly(dis({"f": ["push\t{lr}", f"sub.w\tsp, sp, #{guard}"]}))
    with pytest.raises(ms.StackError, match="could step over it"):
        ms.check_guard(big)


# --------------------------------------------------------------------------------------------
# on QEMU

BUILD = REPO / "build" / "mcu-stack-test"


def _cmake() -> str:
    found = shutil.which("cmake", path=str(Path(sys.executable).parent)) or shutil.which("cmake")
    if found is None:
        pytest.fail("cmake not found (it comes with `make venv`)")
    return found


@pytest.fixture(scope="module")
def programs() -> dict[str, Path]:
    """eskin-mcu and its two stack cases, built with a small model of random support vectors
    and a stream without touches (tools/mcu_case.py's header format)."""
    if shutil.which("qemu-system-arm") is None:
        pytest.skip("qemu-system-arm is not installed (make mcu-deps)")
    if shutil.which("arm-none-eabi-g++") is None:
        pytest.fail("qemu-system-arm is installed but not the cross compiler (make mcu-deps)")
    from eskin import WindowConfig
    from eskin.deploy import write_c_header
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    case = BUILD / "case"
    case.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    pool = rng.standard_normal((12, 4, 4, 20))
    machines = [MachineSpec(k, -1, 0.1 * k, (2, 2, 4), (1.0, 0.5, 2.0), pool[k:k + 8],
                            rng.standard_normal(8)) for k in range(3)]
    spec = ModelSpec(class_names=["brush", "finger", "washer"], rule="one_vs_all",
                     machines=machines, D=20, grid_shape=(4, 4),
                     window_config=WindowConfig(max_window_s=0.5))
    (case / "model.eskin").write_bytes(model_to_bytes(spec, "float32"))
    write_c_header(case / "model.eskin", case / "mcu_model.h", name="mcu_model")
    quiet = np.clip(rng.normal(0, 30, (3000, 16)), -32768, 32767).astype("<i2")
    quiet.tofile(case / "stream.i16")
    (case / "mcu_case.h").write_text(
        "#pragma once\n#include <stdint.h>\n#define MCU_CASE_TAXELS 16\n"
        f"#define MCU_CASE_N_SAMPLES {len(quiet)}\n#define MCU_CASE_N_DECISIONS 0\n"
        "#define MCU_CASE_MAX_DECISIONS 8\n#define MCU_CASE_N_VALUES 3\n"
        "#define MCU_CASE_TOLERANCE 1e-4\n"
        f'#define MCU_CASE_STREAM "{case / "stream.i16"}"\n#include "mcu_model.h"\n'
        "struct McuCaseDecision { long start, stop; int label; double values[3]; };\n"
        "static const McuCaseDecision mcu_case_decisions[1] = {{0, 0, -1, {0}}};\n")
    subprocess.run([_cmake(), "-S", str(REPO), "-B", str(BUILD), "-G", "Ninja",
                    "-DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake", "-DESKIN_DEVICE=ON",
                    "-DCMAKE_BUILD_TYPE=Release",
                    f"-DESKIN_MCU_MODEL_HEADER={case / 'mcu_case.h'}"], cwd=REPO, check=True,
                   stdout=subprocess.DEVNULL)
    names = ("eskin-mcu", "eskin-mcu-deep", "eskin-mcu-overrun")
    subprocess.run([_cmake(), "--build", str(BUILD), "--target", *names], cwd=REPO,
                   check=True, stdout=subprocess.DEVNULL)
    return {n: BUILD / "mcu" / f"{n}.elf" for n in names}


def run(elf: Path) -> tuple[int, str]:
    res = subprocess.run([str(REPO / "mcu" / "run.sh"), str(elf), "120"], capture_output=True,
                         text=True, check=False)
    return res.returncode, res.stdout + res.stderr


def write_need(elf: Path) -> int:
    ms.write_need(elf, 0)  # as linked: not measured
    need, _, _ = ms.decision_need(ms.read_image(elf))
    return need


def test_an_image_without_its_stack_need_refuses_every_model(programs):
    elf = programs["eskin-mcu"]
    write_need(elf)
    status, out = run(elf)
    assert status == 5, out
    assert "eskin-mcu: stack: a decision needs 0 bytes of stack (not measured" in out


def test_the_run_reports_its_high_water_mark_within_the_stack(programs):
    elf = programs["eskin-mcu"]
    need = write_need(elf)
    ms.write_need(elf, need)
    status, out = run(elf)
    assert status == 0, out
    assert f"stack rule: a decision needs {need} bytes" in out
    m = re.search(r"^MCU: .* parity=ok .* stack=(\d+)/(\d+)$", out, re.M)
    assert m, out
    used, size = int(m.group(1)), int(m.group(2))
    assert size == 8192 and 0 < used <= size - ms.guard_bytes()


def test_a_caller_leaving_less_than_a_decision_needs_is_refused_at_construction(programs):
    elf = programs["eskin-mcu-deep"]
    need = write_need(elf)
    ms.write_need(elf, need)
    status, out = run(elf)
    assert status == 5, out
    m = re.search(r"eskin-mcu: stack: a decision needs (\d+) bytes of stack, (\d+) are left", out)
    assert m, out
    assert int(m.group(1)) == need and int(m.group(2)) < need
    assert "MCU:" not in out


def test_without_the_rule_the_overrun_reaches_the_guard(programs):
    elf = programs["eskin-mcu-overrun"]
    ms.write_need(elf, write_need(elf))
    status, out = run(elf)
    assert status == 5, out
    assert "eskin-mcu: stack overflow:" in out and "reached the guard" in out
    assert "MCU:" not in out


def test_the_shipped_program_size_is_the_linked_images(programs):
    """device_budget's program (flash without the model, statics, stack) is the linked image's,
    rounded up to a whole KiB: never below it, never more than that rounding above."""
    from eskin.deploy import CompiledModel, device_budget
    from eskin.deploy.target import TARGETS, program_image

    shipped = program_image("cortex-m4")
    m = size_tool.measure(programs["eskin-mcu"])
    assert 0 < m["model"] and m["program"] > 64 << 10
    assert m["program"] <= shipped["program_flash_bytes"] < m["program"] + 1024
    assert m["statics"] <= shipped["program_statics_bytes"] < m["statics"] + 1024
    assert m["stack"] == shipped["stack_bytes"] == 8192
    t = TARGETS["cortex-m4"]
    assert t.program_flash_bytes == shipped["program_flash_bytes"]
    assert t.program_ram_bytes == shipped["program_statics_bytes"] + shipped["stack_bytes"]
    # the budget's flash of the model compiled into the image is never below the image's
    model = CompiledModel((BUILD / "case" / "model.eskin").read_bytes())
    assert device_budget(model, "cortex-m4").flash_total >= m["flash"] - m["case"]

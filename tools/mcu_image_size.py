"""The program around a model, measured on the linked device images (docs/mcu.md, "Models that
fit"): what `eskin.deploy.device_budget` counts for the program's flash and statics.

    python tools/mcu_image_size.py build/mcu/mcu/eskin-mcu.elf build/mcu/mcu/eskin-fw.elf
    python tools/mcu_image_size.py ELF... --write python/eskin/deploy/cortex_m4_program.json
    python tools/mcu_image_size.py ELF... --check python/eskin/deploy/cortex_m4_program.json

For each image: its flash as the device program prints it (everything the linker places in the
flash region, up to the end of the initial values of ``.data``: ``_sidata + (_edata - _sdata)``),
the model compiled into it (the symbol ``mcu_model_data``, 8-byte aligned: its size rounded up
to 8), the test case's tables (the host's reference decisions in flash and their instruction
counts in RAM: they grow with the case's decisions), the program without them (flash minus the
model and the case) and its statics (``.data`` + ``.bss``, ``_ebss - _sdata``, minus the
case's). ``--write`` stores the largest program and statics over the images, each
rounded up to a whole KiB (so that the figure is never below an image's), with the stack
reserve, in the JSON file the package ships; ``--check`` fails when an image's program or
statics exceed the shipped figures (the file must be written again).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

MODEL_SYMBOL = "mcu_model_data"
KIB = 1024


def _symbols(elf: str | Path) -> dict[str, tuple[int, int]]:
    out = subprocess.run(["arm-none-eabi-nm", "-S", str(elf)], check=True, capture_output=True,
                         text=True).stdout
    syms: dict[str, tuple[int, int]] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4:
            syms[parts[3]] = (int(parts[0], 16), int(parts[1], 16))
        elif len(parts) == 3:
            syms[parts[2]] = (int(parts[0], 16), 0)
    return syms


def measure(elf: str | Path) -> dict[str, int]:
    """flash, model, program (flash without the model) and statics of one image (bytes)."""
    s = _symbols(elf)
    addr = {k: s[k][0] for k in ("_sidata", "_sdata", "_edata", "_ebss")}
    flash = addr["_sidata"] + (addr["_edata"] - addr["_sdata"])
    # the header's array is static (C++: _ZL14mcu_model_data)
    sizes = [v[1] for k, v in s.items() if k in (MODEL_SYMBOL, f"_ZL{len(MODEL_SYMBOL)}{MODEL_SYMBOL}")]
    model = -(-max(sizes) // 8) * 8 if sizes else 0
    stack = s["_stack_size"][0] if "_stack_size" in s else 0
    # the test case's own tables, which grow with its decisions: the host's reference decisions
    # (flash) and the decisions' instruction counts (RAM)
    case_flash = sum(v[1] for k, v in s.items() if "mcu_case_decisions" in k)
    case_ram = sum(v[1] for k, v in s.items() if "g_decision_ticks" in k)
    return {"flash": flash, "model": model, "case": case_flash,
            "program": flash - model - case_flash, "case_ram": case_ram,
            "statics": addr["_ebss"] - addr["_sdata"] - case_ram, "stack": stack}


def _round_up(n: int) -> int:
    return -(-n // KIB) * KIB


def main(argv: list[str]) -> int:
    elfs = [a for a in argv if not a.startswith("--")]
    opts = dict(zip(argv, argv[1:]))
    out_path = opts.get("--write")
    check_path = opts.get("--check")
    elfs = [e for e in elfs if e not in (out_path, check_path)]
    if not elfs:
        print(__doc__)
        return 2
    sizes = {Path(e).name: measure(e) for e in elfs}
    for name, m in sizes.items():
        print(f"{name}: flash {m['flash']} = program {m['program']} + model {m['model']} + "
              f"case {m['case']}; RAM: statics {m['statics']} + case {m['case_ram']}; stack "
              f"{m['stack']}")
    program = max(m["program"] for m in sizes.values())
    statics = max(m["statics"] for m in sizes.values())
    stack = max(m["stack"] for m in sizes.values())
    if out_path:
        version = subprocess.run(["arm-none-eabi-gcc", "-dumpfullversion"], capture_output=True,
                                 text=True, check=False).stdout.strip()
        data = {
            "target": "cortex-m4",
            "program_flash_bytes": _round_up(program),
            "program_statics_bytes": _round_up(statics),
            "stack_bytes": stack,
            "measured": sizes,
            "toolchain": f"arm-none-eabi-gcc {version}",
            "command": "python tools/mcu_image_size.py " + " ".join(elfs) + f" --write {out_path}",
        }
        Path(out_path).write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
        print(f"wrote {out_path}: program {data['program_flash_bytes']} bytes of flash, statics "
              f"{data['program_statics_bytes']} + stack {stack} bytes of RAM")
    if check_path:
        shipped = json.loads(Path(check_path).read_text())
        bad = [f"{n}: program {m['program']} > {shipped['program_flash_bytes']}"
               for n, m in sizes.items() if m["program"] > shipped["program_flash_bytes"]]
        bad += [f"{n}: statics {m['statics']} > {shipped['program_statics_bytes']}"
                for n, m in sizes.items() if m["statics"] > shipped["program_statics_bytes"]]
        bad += [f"{n}: stack {m['stack']} != {shipped['stack_bytes']}"
                for n, m in sizes.items() if m["stack"] and m["stack"] != shipped["stack_bytes"]]
        if bad:
            print(f"FAIL: the images exceed {check_path} (write it again with --write): "
                  + "; ".join(bad))
            return 1
        print(f"ok: the images are within {check_path} (program "
              f"{shipped['program_flash_bytes']} B, statics {shipped['program_statics_bytes']} B)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

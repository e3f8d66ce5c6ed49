"""`make mcu-link`: the controller firmware under QEMU serves the host's unmodified `eskin listen`.

Two steps:

``python tools/mcu_link.py replay CASE OUT.eskr [--per-class 4] [--margin-s 0.5] [--campaign HELD.h5]``
    writes the held-out stream of `make mcu`'s case (tools/mcu_case.py): from its campaign
    (``CASE/campaign.h5``), the recordings of the participant the model was not trained on
    (the last one), ``--per-class`` of each class, each cut to its contact interval and
    ``--margin-s`` seconds of quiet on either side, with 0.5 s gaps (SIMULATED data). With
    ``--campaign HELD.h5`` (``make mcu-link MODEL=... CAMPAIGN=...``): ``--per-class``
    recordings of each of the case's model's classes from that campaign, each cut to the touch
    window the model's own detector finds, with the same margin.

``python tools/mcu_link.py run --elf eskin-fw.elf --model M.eskin --replay R.eskr [--out DIR]``
    starts ``qemu-system-arm -M mps2-an386`` with the firmware on ``-serial pty`` under
    ``-icount shift=3`` (``--icount N`` for another shift; ``--realtime`` for none), the model
    in the firmware's flash slot and the replay in PSRAM (``-device loader``), runs
    ``eskin listen PTY --model M --replay R --until-eof --jsonl DIR/listen.jsonl`` against it
    and ends with one line::

        MCU-LINK: frames=<n> samples=<n> lost=<n> crc_errors=<n> decisions=<n> agree=<k>/<n>

    ``frames``, ``samples``, ``lost`` (samples missing from the stream, as eskin listen counts
    them) and ``crc_errors`` are the host's link statistics; ``decisions`` counts the device's
    DECISION frames and ``agree`` those whose window and label equal a decision of the host's
    own classifier (same model) on the same received stream. Before it, a line ``MCU-FW: ...``
    gives the firmware's own measurements (docs/mcu.md). Exit status 0 only with every sample
    received, none lost, no CRC error, at least one decision and every decision agreeing.

Why ``-icount`` by default: the board's clock then counts the processor's instructions (2^N ns
each; shift 3 is a Cortex-M4 at 125 M instructions per second, slower than the 168 MHz part),
so the sampling timer and the firmware's work share one clock and whether the firmware keeps up
with its work does not depend on how busy the host is; the host receives the same stream, only
at the pace QEMU manages (about 2.5x the stream's duration on a 2-core machine). While the
board idles (WFI), though, QEMU's clock follows the host's: a host that keeps QEMU off the
processor for longer than the sample ring lasts still makes samples due at once and lost. In real time
(``--realtime``) the board's clock is the host's: a host that deschedules QEMU for longer than
the sample ring lasts (256 samples, 85 ms at 3 kSps) makes samples due that the firmware never
had the processor for, and they are lost in its ring although the firmware is fast enough.

QEMU's pty discards what the board writes while no host has it open and notices a host only by
polling; the firmware therefore streams only after the host's START (eskin listen sends START
and INFO_REQUEST when it opens the port).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TICK_HZ = 25e6  # SysTick at the processor clock
DEFAULT_ICOUNT = 3  # 8 ns per instruction: a Cortex-M4 at 125 M instructions per second
LISTEN_NICE = -10  # the listener's priority when permitted (QEMU's: eskin.link.qemu_controller)


def write_replay(case: Path, out: Path, per_class: int, margin_s: float) -> dict:
    import eskin

    camp = eskin.load_campaign(case / "campaign.h5")
    parts = np.unique(camp.participant)
    test = np.flatnonzero(camp.participant == parts[-1])
    chosen: list[int] = []
    for c in np.unique(camp.modality[test]):
        idx = test[camp.modality[test] == c]
        if len(idx) < per_class:
            raise SystemExit(f"{case / 'campaign.h5'}: participant {parts[-1]} has "
                             f"{len(idx)} recordings of class {c}, --per-class is {per_class}")
        chosen.extend(idx[:per_class].tolist())
    chosen.sort()
    rate = float(camp.sample_rate_hz)
    margin = int(round(margin_s * rate))
    recs, labels, contacts = [], [], []
    for i in chosen:
        sig = np.asarray(camp.signals[i])  # (rows, cols, T)
        on, off = (int(v) for v in camp.contact_interval[i])
        a, b = max(0, on - margin), min(sig.shape[-1], off + margin)
        recs.append(np.ascontiguousarray(sig[..., a:b]).astype(np.int16))
        labels.append(int(camp.modality[i]))
        contacts.append((on - a, off - a))
    from eskin.data.replay import write_replay_arrays

    write_replay_arrays(
        out, recs, labels=labels, class_names=list(camp.modality_names), sample_rate_hz=rate,
        volts_per_count=float(camp.volts_per_count), contact_intervals=np.asarray(contacts),
        recording_indices=chosen, gap_s=0.5, seed=0)
    n = sum(r.shape[-1] for r in recs) + int(round(0.5 * rate)) * (len(recs) + 1)
    return {"recordings": len(chosen), "classes": len(set(labels)), "seconds": n / rate}


def write_user_replay(case: Path, campaign: Path, out: Path, per_class: int,
                      margin_s: float) -> dict:
    """The stream of a user's held-out campaign for the case's model (``CASE/model.eskin``, from
    ``tools/mcu_case.py --model M --campaign HELD``): ``per_class`` recordings of each of the
    model's classes, each cut to the touch window the model's own detector finds in it (a
    user's campaign has no contact intervals) with ``margin_s`` seconds on either side, so that
    the stream fits the board's memory; 0.5 s gaps."""
    import eskin
    from eskin.data.replay import write_replay_arrays
    from eskin.signal.preprocess import WindowConfig, detect_touches

    compiled = eskin.CompiledModel(case / "model.eskin")
    config = WindowConfig.from_array(
        np.array([compiled.window_config[k] for k in WindowConfig.field_names()]))
    try:
        camp = eskin.load_campaign(campaign)
    except (OSError, ValueError) as exc:
        raise SystemExit(f"{campaign}: {exc}") from None
    names = np.asarray(camp.modalities, dtype=object)[np.asarray(camp.modality)]
    chosen = sorted(i for c in compiled.class_names
                    for i in np.flatnonzero(names == c)[:per_class].tolist())
    if not chosen:
        raise SystemExit(f"{campaign}: no recording of the model's classes "
                         f"({', '.join(compiled.class_names)})")
    rate = float(camp.sample_rate_hz)
    margin = int(round(margin_s * rate))
    recs, labels = [], []
    for i in chosen:
        sig = np.asarray(camp.recording(i))[..., : int(camp.lengths[i])]
        w = detect_touches(sig[None], sample_rate_hz=rate, config=config)
        a, b = max(0, int(w.start[0]) - margin), min(sig.shape[-1], int(w.stop[0]) + margin)
        recs.append(np.ascontiguousarray(sig[..., a:b]).astype(np.int16))
        labels.append(list(camp.modalities).index(names[i]))
    write_replay_arrays(out, recs, labels=labels, class_names=list(camp.modalities),
                        sample_rate_hz=rate, volts_per_count=float(camp.volts_per_count),
                        recording_indices=chosen, gap_s=0.5, seed=0)
    n = sum(r.shape[-1] for r in recs) + int(round(0.5 * rate)) * (len(recs) + 1)
    return {"recordings": len(chosen), "classes": len(set(labels)), "seconds": n / rate,
            "source": str(campaign)}


def fw_measurements(line: str, icount: int | None, rate_hz: float) -> dict:
    """The firmware's FW: line as numbers. Under -icount shift=N one instruction takes 2^N ns
    of the board's clock, so a SysTick tick (40 ns) is 40 / 2^N instructions: instruction
    counts are given then (in real time, only times)."""
    kv = dict(tok.split("=", 1) for tok in line.split()[1:])
    v = {k: int(x) for k, x in kv.items()}
    total_s = v["total_ticks"] / TICK_HZ
    out = {
        "samples": v["samples"], "lost_in_ring": v["lost"], "dropped": v["dropped"],
        "ring_high_water": v["ring_high_water"], "decisions": v["decisions"],
        "uart_bytes": v["uart_bytes"], "encode_errors": v["encode_errors"],
        "decisions_made": v["decisions_made"], "decisions_dropped": v["decisions_dropped"],
        "frames_dropped": v["frames_dropped"],
    }
    if icount is not None and v["profile"]:
        # the board's clock counts instructions here; in real time it is QEMU's SysTick, which
        # loses wrap-arounds while the host deschedules QEMU, so no rate is taken from it then
        out["board_stream_s"] = round(total_s, 3)
        out["busy_fraction"] = round(v["busy_ticks"] / max(v["total_ticks"], 1), 4)
        ipt = 1e9 / TICK_HZ / 2 ** icount  # instructions per tick
        # each handler reads the clock twice to account for itself: that pair is taken off
        pair = v["clock_pair_ticks_x256"] / 256 * ipt
        out["clock_pair_instructions"] = round(pair, 1)
        out["isr_instructions_per_sample"] = round(
            v["sampler_isr_ticks"] * ipt / max(v["samples"], 1) - pair)
        # the TX handler sends a run of bytes per interrupt: its clock pair is taken off per
        # interrupt (the RX handler's few bytes are in the same count)
        out["uart_tx_interrupts"] = v["uart_tx_irqs"]
        out["uart_isr_instructions_per_byte"] = round(
            (v["uart_isr_ticks"] * ipt - pair * v["uart_tx_irqs"]) / max(v["uart_bytes"], 1), 1)
        # the processor's work per sample (main loop and handlers), at the replay's rate
        per_sample = v["busy_ticks"] * ipt / max(v["samples"], 1)
        out["busy_instructions_per_sample"] = round(per_sample)
        out["instructions_per_s_at_rate"] = round(per_sample * rate_hz)
        out["headroom_at_168MHz"] = round(1 - per_sample * rate_hz / 168e6, 4)
        out["longest_push_instructions"] = round(v["longest_push_ticks"] * ipt)
        out["longest_push_ms_at_168MHz"] = round(v["longest_push_ticks"] * ipt / 168e3, 2)
    return out


def run(args: argparse.Namespace) -> int:
    """Runs the link up to ``--attempts`` times: again only in real time (``--realtime``) and
    only when the one fault was samples lost in the firmware's ring (the emulator fell behind
    real time on a busy host: QEMU carries each UART byte with a write(2) on the pty), never for
    a CRC error or a fault without such losses. Each attempt prints its lines."""
    code = 1
    for attempt in range(1, max(1, args.attempts) + 1):
        code, emulator_behind = _run_once(args)
        if code == 0 or not emulator_behind or args.icount is not None \
                or attempt == args.attempts:
            return code
        print(f"mcu-link: attempt {attempt} lost samples in the firmware's ring (the emulator "
              f"fell behind real time: is the host busy?); running again", file=sys.stderr)
    return code


def _run_once(args: argparse.Namespace) -> tuple[int, bool]:
    """One run: (exit status, whether the only fault was samples lost in the firmware's ring)."""
    from eskin.data.replay import read_replay_file
    from eskin.link.qemu_controller import QemuController, QemuControllerError, priority

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    rp = read_replay_file(args.replay)
    stream_s = rp.samples.shape[0] / rp.sample_rate_hz
    jsonl = out / "listen.jsonl"
    try:
        # profiling (the firmware timing itself) only where it costs instructions alone
        with QemuController(args.model, args.replay, out, elf=args.elf,
                            icount=args.icount) as qc:
            listen = priority(LISTEN_NICE) + [
                sys.executable, "-m", "eskin", "listen", qc.pty, "--model", str(args.model),
                "--replay", str(args.replay), "--until-eof", "--jsonl", str(jsonl), "--force",
                "--view", "plain"]
            # under -icount the stream comes at QEMU's pace: about 2.5x its duration when idle
            pace = 4 if args.icount is None else 10
            timeout = args.timeout if args.timeout else 120 + pace * stream_s
            with open(out / "listen.log", "wb") as log:
                r = subprocess.run(listen, stdout=log, stderr=subprocess.STDOUT, timeout=timeout)
    except QemuControllerError as exc:
        print(f"mcu-link: {exc}", file=sys.stderr)
        return 2, False
    except subprocess.TimeoutExpired as exc:
        print(f"mcu-link: eskin listen did not finish in {exc.timeout:.0f} s (see "
              f"{out / 'listen.log'} and {out / 'qemu.log'})", file=sys.stderr)
        return 1, False
    if r.returncode != 0:
        print((out / "listen.log").read_text()[-2000:], file=sys.stderr)
        print(f"mcu-link: eskin listen exited with {r.returncode}", file=sys.stderr)
        return 1, False

    rows = [json.loads(x) for x in jsonl.read_text().splitlines() if x.strip()]
    stats = next(r for r in rows if r.get("type") == "stats")
    dev = [r for r in rows if r.get("type") == "decision" and r["source"] == "controller"]
    host = [r for r in rows if r.get("type") == "decision" and r["source"] == "host"]
    host_keys = {(h["onset_sample"], h["offset_sample"], h["label_index"]) for h in host}
    agree = sum((d["onset_sample"], d["offset_sample"], d["label_index"]) in host_keys for d in dev)
    fw_line = next((x for x in (out / "qemu.log").read_text(errors="replace").splitlines()
                    if x.startswith("FW: ")), None)
    ring_lost = 0
    if fw_line is not None:
        fw = fw_measurements(fw_line, args.icount, float(rp.sample_rate_hz))
        fw["longest_latency_us"] = max((d["latency_us"] for d in dev), default=0)
        # the host's clock: how fast the stream really came (below the replay's rate when QEMU
        # could not deliver every timer period on a busy machine)
        el = max(float(stats.get("elapsed_s", 0.0)), 1e-9)
        fw["host_elapsed_s"] = round(el, 1)
        fw["host_samples_per_s"] = round(int(stats["samples"]) / el, 1)
        fw["host_bytes_per_s"] = round(int(stats["bytes"]) / el)
        ring_lost = int(fw["lost_in_ring"])
        print("MCU-FW: " + json.dumps(fw))
        (out / "fw.json").write_text(json.dumps(fw, indent=1) + "\n")
    else:
        print("MCU-FW: the firmware printed no FW: line (see qemu.log)")
    n_samples = int(rp.samples.shape[0])
    lost = max(int(stats["lost_samples"]), n_samples - int(stats["samples"]))
    n = len(dev)
    dropped = int(stats.get("controller_decisions_dropped", 0))
    print(f"MCU-LINK: frames={stats['frames']} samples={stats['samples']} lost={lost} "
          f"crc_errors={stats['crc_errors']} decisions={n} decisions_dropped={dropped} "
          f"agree={agree}/{n}")
    others_ok = (stats["crc_errors"] == 0 and n > 0 and agree == n and len(host) == n
                 and dropped == 0)
    if len(host) != n:
        print(f"mcu-link: the host made {len(host)} decisions, the device {n}", file=sys.stderr)
    if lost == 0 and others_ok:
        return 0, False
    # lost samples also move the windows of both sides: a disagreement then is their effect
    return 1, ring_lost > 0 and stats["crc_errors"] == 0


def _terminate(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)  # unwinds: QEMU and the listener are stopped on the way


def main(argv: list[str] | None = None) -> int:
    import signal

    signal.signal(signal.SIGTERM, _terminate)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("replay", help="the held-out stream of make mcu's case")
    r.add_argument("case", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--per-class", type=int, default=4)
    r.add_argument("--margin-s", type=float, default=0.5)
    r.add_argument("--campaign", type=Path, default=None,
                   help="a user's held-out campaign for the case's model (make mcu-link "
                        "MODEL=... CAMPAIGN=...) instead of the case's own")
    x = sub.add_parser("run", help="QEMU + eskin listen, then the MCU-LINK line")
    x.add_argument("--elf", type=Path, required=True)
    x.add_argument("--model", type=Path, required=True)
    x.add_argument("--replay", type=Path, required=True)
    x.add_argument("--out", type=Path, default=Path("build/mcu/link"))
    x.add_argument("--icount", type=int, default=DEFAULT_ICOUNT,
                   help="run QEMU with -icount shift=N: the board's clock counts instructions, "
                        "2^N ns each (default %(default)s: 125 M instructions per second)")
    x.add_argument("--realtime", action="store_true",
                   help="run QEMU without -icount: the board's clock is the host's, and a busy "
                        "host can make the firmware lose samples it would have kept")
    x.add_argument("--timeout", type=float, default=None, help="seconds for eskin listen")
    x.add_argument("--attempts", type=int, default=1,
                   help="run again (up to N runs in all) when the only fault is samples lost in "
                        "the firmware's ring: the emulator fell behind real time (--realtime only)")
    a = ap.parse_args(argv)
    if a.cmd == "run" and a.realtime:
        a.icount = None
    if a.cmd == "replay":
        if a.campaign is not None:
            info = write_user_replay(a.case, a.campaign, a.out, a.per_class, a.margin_s)
            print(f"{a.out}: {info['recordings']} recordings of {info['classes']} classes of "
                  f"{info['source']}, {info['seconds']:.1f} s at the campaign's rate")
            return 0
        info = write_replay(a.case, a.out, a.per_class, a.margin_s)
        print(f"{a.out}: {info['recordings']} held-out recordings of {info['classes']} classes, "
              f"{info['seconds']:.1f} s at the campaign's rate (SIMULATED data)")
        return 0
    return run(a)


if __name__ == "__main__":
    sys.exit(main())

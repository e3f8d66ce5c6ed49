"""The live page's cost to the listener: `eskin listen`'s loop (LinkListener, a host model) on
`eskin-fw-sim` at several speeds, each run twice: without the page, and with the page served
(eskin.link.web, its own thread) and open in a headless chromium. Baseline: the same run
without the page, in the same invocation.

Prints, per speed and case: samples received, lost (holes in the indices, reconciled with the
controller's count) and dropped by the controller, the wall time, the listener thread's CPU
time, and with the page the server thread's CPU time as a ratio to the listener's, display
frames sent and DATA blocks the page skipped (it skips display data, never samples).

    python benchmarks/bench_web.py [--seconds 60] [--speeds 0,1,2,5,10]

Speed 0 is unpaced (the simulator waits for the host: nothing can be lost, the figure is the
throughput); paced speeds lose samples when the host does not read in time.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from web_data import make_case  # noqa: E402  (the tests' small real model and replay)

from eskin.link.listener import DataBlock, LinkListener  # noqa: E402
from eskin.link.web import LiveState, WebServer  # noqa: E402


def open_page(url: str, nice: int = 0) -> subprocess.Popen:
    """A headless chromium showing ``url`` (it runs the page's script: WebSocket, drawing)."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        sys.exit("bench_web.py: chromium is not installed (apt-get install chromium)")
    flags = ["--headless=new", "--disable-gpu", "--no-first-run", "--disable-extensions",
             "--window-size=1280,1000", f"--user-data-dir={tempfile.mkdtemp(prefix='chr-')}",
             "--remote-debugging-port=0"]  # keeps the headless browser running
    if os.geteuid() == 0:
        flags.append("--no-sandbox")
    return subprocess.Popen([*(["nice", "-n", str(nice)] if nice else []), browser, *flags,
                             url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def start_sim(replay: Path, *args: object) -> tuple[subprocess.Popen, str]:
    """eskin-fw-sim with its default transmit queue (16 KiB: a host that does not read in
    time loses samples), holding the port 2 s after the replay so the host reads the end."""
    from eskin._paths import find_executable

    proc = subprocess.Popen([str(find_executable("eskin-fw-sim")), str(replay),
                             *map(str, args), "--hold", "2", "--quiet"],
                            stdout=subprocess.PIPE, text=True)
    first = proc.stdout.readline().split() if proc.stdout else []
    if not first or first[0] != "PTY":
        sys.exit(f"bench_web.py: eskin-fw-sim did not start: {first}")
    return proc, first[1]


def cpu_of(proc: subprocess.Popen) -> float:
    """CPU seconds of a process and its children so far (psutil)."""
    import psutil

    try:
        p = psutil.Process(proc.pid)
        procs = [p, *p.children(recursive=True)]
    except psutil.NoSuchProcess:
        return 0.0
    total = 0.0
    for q in procs:
        try:
            t = q.cpu_times()
            total += t.user + t.system
        except psutil.NoSuchProcess:
            pass
    return total


def run(model: Path, replay: Path, speed: float, page: bool, nice: int = 0,
        tick_hz: float = 15.0) -> dict:
    sim, pty = start_sim(replay, "--model", model, "--speed", speed, "--tick", 10,
                         "--wait-start")
    server = browser = None
    cpu0 = browser0 = 0.0
    state = LiveState(pty) if page else None
    try:
        if state is not None:
            server = WebServer(state, "127.0.0.1", 0, tick_hz=tick_hz).start()
            browser = open_page(server.url, nice)
            deadline = time.monotonic() + 60
            while server.clients == 0:  # the page has loaded and holds its WebSocket
                if time.monotonic() > deadline:
                    sys.exit("bench_web.py: the page did not connect within 60 s")
                time.sleep(0.05)
            time.sleep(0.5)
            cpu0 = server.cpu_s  # starting up and serving the page's first load left out
            browser0 = cpu_of(browser)
        with LinkListener(pty, model=model, replay=replay, stats_interval=0.25) as link:
            t_cpu, t_wall = time.thread_time(), time.perf_counter()
            events = link.events(until_eof=True, duration=600)
            if state is not None:
                events = state.observed(events, lambda: link.stats)
            holes = []  # (seconds into the run, samples lost) of the first holes
            for ev in events:
                if isinstance(ev, DataBlock) and ev.lost_before and len(holes) < 4:
                    holes.append((round(time.perf_counter() - t_wall, 2), ev.lost_before))
            cpu, wall = time.thread_time() - t_cpu, time.perf_counter() - t_wall
            stats = link.stats
        out = {"speed": speed, "page": page, "nice": nice, "samples": stats.samples,
               "lost": stats.lost_samples, "dropped": stats.controller_dropped_samples,
               "wall_s": wall, "listener_cpu_s": cpu, "holes": holes}
        if server is not None and state is not None:
            clients = server.clients
            server.stop()  # its thread's CPU time is final once it has ended
            out.update(server_cpu_s=server.cpu_s - cpu0, clients=clients,
                       browser_cpu_s=cpu_of(browser) - browser0,
                       blocks_skipped=state.blocks_dropped, frames_dropped=server.frames_dropped)
        return out
    finally:
        if server is not None:
            server.stop()
        if browser is not None:
            browser.terminate()
            browser.wait(30)
        sim.terminate()
        sim.communicate(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0,
                    help="seconds of signal in the replay (recordings of 1 s and their gaps)")
    ap.add_argument("--speeds", default="0,1,2,5,10")
    ap.add_argument("--nice", type=int, default=0,
                    help="also run each speed with the page open in a chromium run under "
                         "`nice -n N` (the listener keeps the processor first)")
    ap.add_argument("--tick-hz", type=float, default=15.0, help="display frames a second")
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-web-"))
    model, replay = make_case(folder, recordings=max(1, int(args.seconds / 1.4)))
    print(f"replay: {replay} ({args.seconds:g} s of signal, 4x4 taxels, 3000 samples/s); "
          f"host model {model.name}")
    rows = []
    for speed in (float(s) for s in args.speeds.split(",")):
        for page, nice in ((False, 0), (True, 0), *([(True, args.nice)] if args.nice else [])):
            r = run(model, replay, speed, page, nice, args.tick_hz)
            rows.append(r)
            extra = ""
            if page:
                extra = (f" server cpu {r['server_cpu_s']:.2f} s = "
                         f"{r['server_cpu_s'] / r['listener_cpu_s']:.3f} x listener; "
                         f"chromium cpu {r['browser_cpu_s']:.1f} s; "
                         f"display blocks skipped {r['blocks_skipped']}")
            case = f"page open{f' (nice {nice})' if nice else ''}" if page else "no page"
            print(f"speed {speed:g} {case:<19}: "
                  f"samples {r['samples']} lost {r['lost']} dropped {r['dropped']} "
                  f"wall {r['wall_s']:.1f} s listener cpu {r['listener_cpu_s']:.2f} s{extra}"
                  + (f"; first holes (s into the run, samples) {r['holes']}" if r["holes"] else ""),
                  flush=True)
    print("\nsummary:")
    for s in sorted({r["speed"] for r in rows}):
        a, b = (next(r for r in rows if r["speed"] == s and r["page"] == p and not r["nice"])
                for p in (0, 1))
        tput = (f"; throughput {a['samples'] / a['wall_s'] / 3000:.0f}x vs "
                f"{b['samples'] / b['wall_s'] / 3000:.0f}x real time" if s == 0 else "")
        print(f"  speed {s:g}: samples lost without the page {a['lost']}, with the page open "
              f"{b['lost']}; server/listener CPU "
              f"{b['server_cpu_s'] / b['listener_cpu_s']:.3f}{tput}")
        for c in (r for r in rows if r["speed"] == s and r["nice"]):
            print(f"  speed {s:g}: with the page open in chromium under nice -n {c['nice']}: "
                  f"samples lost {c['lost']}; server/listener CPU "
                  f"{c['server_cpu_s'] / c['listener_cpu_s']:.3f}")
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

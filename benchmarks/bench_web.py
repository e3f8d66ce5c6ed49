"""The live page's cost to the listener: `eskin listen`'s loop (LinkListener, a host model) on
`eskin-fw-sim` at several speeds, each run without the page and with the page served
(eskin.link.web, its own thread) and open in a headless chromium. Baseline: the same run
without the page, in the same invocation; the two cases alternate (without, with; then with,
without) so that both see the same load from the machine's other programs.

Prints, per run: samples received, lost (holes in the indices, reconciled with the
controller's count) and dropped by the controller, how late the simulator was (its pacing
p99), the wall time, the listener thread's CPU time, the most bytes the port's reading thread
held for the loop, the load average before and after; with the page the server thread's CPU
time (also as a ratio to the listener's), chromium's CPU time (all its processes) and DATA
blocks the page skipped (display data, never samples). Then a summary per speed.

    python benchmarks/bench_web.py [--seconds 60] [--speeds 0,1,5,10] [--repeat 2]

Speed 0 is unpaced (the simulator waits for the host: nothing can be lost, the figure is the
throughput); paced speeds lose samples when the host does not read in time. The simulator
stands for a controller with a processor of its own: as root it runs under SCHED_FIFO
(`--sim-fifo`, `chrt`), so that a simulator kept from the processor does not count against
the host. Chromium runs in a scheduling group of its own (setsid: Linux's autogroup), as a
browser the user starts does.
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


def open_page(url: str, nice: int = 0, own_session: bool = True) -> subprocess.Popen:
    """A headless chromium showing ``url`` (it runs the page's script: WebSocket, drawing);
    ``own_session``: after setsid, in a scheduling group of its own, as a browser the user
    starts is (Linux's autogroup scheduling shares the processors between such groups first)."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        sys.exit("bench_web.py: chromium is not installed (apt-get install chromium)")
    flags = ["--headless=new", "--disable-gpu", "--no-first-run", "--disable-extensions",
             "--window-size=1280,1000", f"--user-data-dir={tempfile.mkdtemp(prefix='chr-')}",
             "--remote-debugging-port=0"]  # keeps the headless browser running
    if os.geteuid() == 0:
        flags.append("--no-sandbox")
    proc = subprocess.Popen([*(["nice", "-n", str(nice)] if nice else []), browser, *flags,
                             url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=own_session)
    group = Path(f"/proc/{proc.pid}/autogroup")
    deadline = time.monotonic() + 5
    while own_session and os.getsid(proc.pid) != proc.pid and time.monotonic() < deadline:
        time.sleep(0.001)  # its autogroup exists once the child has called setsid
    if nice and own_session and group.exists() and os.getsid(proc.pid) == proc.pid:
        try:
            group.write_text(str(nice))
        except OSError as exc:
            print(f"bench_web.py: chromium's autogroup keeps its priority ({exc})", flush=True)
    return proc


def start_sim(replay: Path, *args: object, fifo: int = 0) -> tuple[subprocess.Popen, str]:
    """eskin-fw-sim with its default transmit queue (16 KiB: a host that does not read in
    time loses samples), holding the port 2 s after the replay so the host reads the end. It
    stands for a controller, which has a processor of its own: it runs after setsid (a
    scheduling group of its own) and, with ``fifo`` > 0, under the real-time policy SCHED_FIFO at that priority (`chrt`),
    ahead of every ordinary program, so that what is measured is the host (a simulator kept
    from the processor sends the samples it owes in a burst that no host's buffers could take:
    ``controller_pacing_p99_us`` says how late it was)."""
    from eskin._paths import find_executable

    proc = subprocess.Popen([*(["chrt", "-f", str(fifo)] if fifo else []),
                             str(find_executable("eskin-fw-sim")), str(replay),
                             *map(str, args), "--hold", "2", "--quiet"],
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
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


def run(model: Path, replay: Path, speed: float, page: bool, args: argparse.Namespace,
        loop_reads: bool = False) -> dict:
    """One run; ``loop_reads``: the baseline listener that reads the port in its own loop
    (no reading thread)."""
    nice, tick_hz, own_session, settle_s = args.nice, args.tick_hz, not args.same_group, \
        args.settle
    sim, pty = start_sim(replay, "--model", model, "--speed", speed, "--tick", 10,
                         "--wait-start", fifo=args.sim_fifo)
    server = browser = None
    cpu0 = browser0 = 0.0
    state = LiveState(pty) if page else None
    try:
        if state is not None:
            rate = {} if tick_hz is None else {"tick_hz": tick_hz}
            server = WebServer(state, "127.0.0.1", 0, **rate).start()
            browser = open_page(server.url, nice, own_session)
            deadline = time.monotonic() + 60
            while server.clients == 0:  # the page has loaded and holds its WebSocket
                if time.monotonic() > deadline:
                    sys.exit("bench_web.py: the page did not connect within 60 s")
                time.sleep(0.05)
            time.sleep(settle_s)  # the page has drawn its first state, chromium settles
            cpu0 = server.cpu_s  # starting up and serving the page's first load left out
            browser0 = cpu_of(browser)
        load0 = os.getloadavg()[0]
        queue = {"read_queue_bytes": 0} if loop_reads else {}
        with LinkListener(pty, model=model, replay=replay, stats_interval=0.25, **queue) as link:
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
            backlog = link.read_backlog_peak
        out = {"speed": speed, "page": page, "loop_reads": loop_reads, "samples": stats.samples,
               "lost": stats.lost_samples, "dropped": stats.controller_dropped_samples,
               "pacing_p99_us": stats.controller_pacing_p99_us,
               "wall_s": wall, "listener_cpu_s": cpu, "holes": holes,
               "backlog_kib": backlog / 1024, "load": (load0, os.getloadavg()[0])}
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


def _case(r: dict) -> str:
    return ("page open" if r["page"] else "no page") + (" (loop reads)" if r["loop_reads"] else "")


def _line(r: dict) -> str:
    extra = ""
    if r["page"]:
        extra = (f" server cpu {r['server_cpu_s']:.2f} s = "
                 f"{r['server_cpu_s'] / r['listener_cpu_s']:.3f} x listener; "
                 f"chromium cpu {r['browser_cpu_s']:.1f} s; "
                 f"display blocks skipped {r['blocks_skipped']}")
    return (f"speed {r['speed']:g} {_case(r):<22}: samples {r['samples']} lost {r['lost']} "
            f"dropped {r['dropped']} (simulator pacing p99 {r['pacing_p99_us']:.0f} us) wall {r['wall_s']:.1f} s listener cpu "
            f"{r['listener_cpu_s']:.2f} s read backlog peak {r['backlog_kib']:.0f} KiB; "
            f"load average {r['load'][0]:.1f} -> {r['load'][1]:.1f}{extra}"
            + (f"; first holes (s into the run, samples) {r['holes']}" if r["holes"] else ""))


def _summary(rows: list[dict]) -> None:
    print("\nsummary (per speed: every run, in the order run):")
    for s, loop in sorted({(r["speed"], r["loop_reads"]) for r in rows}):
        a = [r for r in rows if r["speed"] == s and not r["page"] and r["loop_reads"] == loop]
        b = [r for r in rows if r["speed"] == s and r["page"] and r["loop_reads"] == loop]
        loads = [x for r in a + b for x in r["load"]]
        ratio = [r["server_cpu_s"] / r["listener_cpu_s"] for r in b]
        rt = [r["server_cpu_s"] / r["wall_s"] for r in b]
        tput = ""
        if s == 0:
            tput = (f"; throughput {max(r['samples'] / r['wall_s'] for r in a) / 3000:.0f}x vs "
                    f"{max(r['samples'] / r['wall_s'] for r in b) / 3000:.0f}x real time")
        who = "the loop reads the port" if loop else "a reading thread"
        print(f"  speed {s:g}, {who}: samples lost without the page {[r['lost'] for r in a]}, with "
              f"the page open {[r['lost'] for r in b]}; server CPU / listener CPU "
              f"{min(ratio):.3f}-{max(ratio):.3f}, server CPU {100 * min(rt):.1f}-"
              f"{100 * max(rt):.1f} % of a core; listener CPU without / with the page "
              f"{sum(r['listener_cpu_s'] for r in a) / len(a):.2f} / "
              f"{sum(r['listener_cpu_s'] for r in b) / len(b):.2f} s; chromium CPU "
              f"{[round(r['browser_cpu_s'], 1) for r in b]} s; read backlog peak "
              f"{max(r['backlog_kib'] for r in a + b):.0f} KiB; load average "
              f"{min(loads):.1f}-{max(loads):.1f}{tput}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0,
                    help="seconds of signal in the replay (recordings of 1 s and their gaps)")
    ap.add_argument("--speeds", default="0,1,5,10")
    ap.add_argument("--repeat", type=int, default=2,
                    help="pairs of runs per speed (without / with the page, in turn)")
    ap.add_argument("--nice", type=int, default=0,
                    help="run chromium under `nice -n N`, its autogroup too (Linux; "
                         "default 0: the same priority as every program)")
    ap.add_argument("--sim-fifo", type=int, default=10 if os.geteuid() == 0 else 0,
                    help="run eskin-fw-sim under SCHED_FIFO at priority N (`chrt -f N`; default "
                         "10 as root, else 0: not): it stands for a controller with a "
                         "processor of its own")
    ap.add_argument("--settle", type=float, default=0.5,
                    help="seconds between the page's connection and the stream's start")
    ap.add_argument("--same-group", action="store_true",
                    help="start chromium in the benchmark's scheduling group (by default it "
                         "calls setsid: a group of its own, as a browser the user opens has)")
    ap.add_argument("--baseline", action="store_true",
                    help="also run the listener that reads the port in its own loop, without "
                         "the reading thread (LinkListener(read_queue_bytes=0)), in turn")
    ap.add_argument("--tick-hz", type=float, default=None,
                    help="display frames a second (default: the server's)")
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-web-"))
    model, replay = make_case(folder, recordings=max(1, int(args.seconds / 1.4)))
    print(f"replay: {replay} ({args.seconds:g} s of signal, 4x4 taxels, 3000 samples/s); "
          f"host model {model.name}; {os.cpu_count()} cores; chromium "
          f"{'in this scheduling group' if args.same_group else 'in a group of its own'}"
          f"{f' under nice -n {args.nice}' if args.nice else ''}; eskin-fw-sim in a group "
          f"of its own{f' under chrt -f {args.sim_fifo}' if args.sim_fifo else ''}; display "
          f"{args.tick_hz or 'at the server default'} frames/s")
    rows = []
    for speed in (float(s) for s in args.speeds.split(",")):
        for k in range(args.repeat):
            for loop_reads in ((False, True) if args.baseline else (False,)):
                for page in ((False, True) if k % 2 == 0 else (True, False)):
                    r = run(model, replay, speed, page, args, loop_reads)
                    rows.append(r)
                    print(_line(r), flush=True)
    _summary(rows)
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

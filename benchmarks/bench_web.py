"""The live page's cost to the listener: `eskin listen`'s loop (LinkListener, a host model) on
`eskin-fw-sim` at several speeds, each run in several cases, in turn within one invocation
(forwards, then backwards) so that all see the same load from the machine's other programs:

- none: no page served (the baseline);
- open: the page served (eskin.link.web, its own thread) and opened in a tab of a headless
  chromium, loaded (the browser back to idle) before the stream starts;
- opening: the page served and its tab opened during the stream (at a quarter of it);
- blank: no page served, a blank tab (about:blank) opened during the stream, as in "opening":
  what opening any tab costs;
- launch: the page served and a second chromium started on it, the stream starting 0.5 s after
  the page has connected: what this adds is the browser's own start-up.

One chromium is started before the first run and left running (idle, a blank tab) as a user's
browser is; tabs are opened and closed through its DevTools HTTP endpoint. Chromium runs in a
scheduling group of its own (setsid: Linux's autogroup), as a browser the user starts does.

Prints, per run: samples received, lost (holes in the indices, reconciled with the
controller's count) and dropped by the controller, how late the simulator was (its pacing
p99), the wall time, the listener thread's CPU time, the most bytes the port's reading thread
held for the loop, how long that thread waited for a processor while runnable (its
run-queue time, /proc/self/task/*/schedstat), the load average before and after, chromium's
CPU time over the stream (all its processes); with the page the server thread's CPU time (as a
ratio to the listener's, and per second of stream) and DATA blocks the page skipped (display
data, never samples). Then a summary per speed.

    python benchmarks/bench_web.py [--seconds 60] [--speeds 0,1,5,10] [--repeat 2]
        [--cases none,open,opening] [--ordinary-reader] [--baseline]

Speed 0 is unpaced (the simulator waits for the host: nothing can be lost, the figure is the
throughput); paced speeds lose samples when the host does not read in time. The simulator
stands for a controller with a processor of its own: as root it runs under SCHED_FIFO
(`--sim-fifo`, `chrt`), so that a simulator kept from the processor does not count against
the host.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from web_data import make_case  # noqa: E402  (the tests' small real model and replay)

from eskin.link.listener import DataBlock, LinkListener  # noqa: E402
from eskin.link.web import LiveState, WebServer  # noqa: E402


class Browser:
    """A headless chromium, started once and left running as a user's browser is, in a
    scheduling group of its own (setsid: Linux's autogroup shares the processors between such
    groups first); pages are opened in new tabs and closed through its DevTools HTTP endpoint.
    Its CPU time: all its processes (psutil)."""

    def __init__(self, nice: int = 0, own_session: bool = True, url: str = "about:blank",
                 wait_quiet: bool = True) -> None:
        browser = shutil.which("chromium") or shutil.which("chromium-browser")
        if browser is None:
            sys.exit("bench_web.py: chromium is not installed (apt-get install chromium)")
        self.profile = tempfile.mkdtemp(prefix="chr-")
        flags = ["--headless=new", "--disable-gpu", "--no-first-run", "--disable-extensions",
                 "--window-size=1280,1000", f"--user-data-dir={self.profile}",
                 "--remote-debugging-port=0"]  # its port is written to DevToolsActivePort
        if os.geteuid() == 0:
            flags.append("--no-sandbox")
        self.proc = subprocess.Popen([*(["nice", "-n", str(nice)] if nice else []), browser,
                                      *flags, url], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=own_session)
        _renice_group(self.proc, nice, own_session)
        active = Path(self.profile) / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (active.exists() and active.read_text().strip()):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                sys.exit("bench_web.py: chromium did not start within 60 s")
            time.sleep(0.05)
        self.devtools = f"http://127.0.0.1:{active.read_text().split()[0]}/json"
        if wait_quiet:
            self.quiet()

    def _call(self, path: str, method: str = "GET") -> bytes:
        import urllib.request

        req = urllib.request.Request(f"{self.devtools}/{path}", method=method)
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.read()

    def open(self, url: str) -> str:
        """Open ``url`` in a new tab: its target id."""
        import json

        return json.loads(self._call(f"new?{url}", "PUT"))["id"]

    def close(self, target: str) -> None:
        self._call(f"close/{target}")

    def cpu(self) -> float:
        return cpu_of(self.proc)

    def quiet(self, below: float = 0.05, over_s: float = 0.5, timeout: float = 30.0) -> float:
        """Wait until the browser uses less than ``below`` of a core over ``over_s``; the
        seconds waited."""
        t0 = time.monotonic()
        c = self.cpu()
        while time.monotonic() - t0 < timeout:
            time.sleep(over_s)
            c, c0 = self.cpu(), c
            if c - c0 < below * over_s:
                break
        return time.monotonic() - t0

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(30)
        shutil.rmtree(self.profile, ignore_errors=True)


def _renice_group(proc: subprocess.Popen, nice: int, own_session: bool) -> None:
    """With ``nice``, the process's autogroup under that niceness too (Linux)."""
    group = Path(f"/proc/{proc.pid}/autogroup")
    deadline = time.monotonic() + 5
    while own_session and os.getsid(proc.pid) != proc.pid and time.monotonic() < deadline:
        time.sleep(0.001)  # its autogroup exists once the child has called setsid
    if nice and own_session and group.exists() and os.getsid(proc.pid) == proc.pid:
        try:
            group.write_text(str(nice))
        except OSError as exc:
            print(f"bench_web.py: chromium's autogroup keeps its priority ({exc})", flush=True)


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


def reader_schedstat() -> tuple[float, int]:
    """The port's reading thread (the newest thread of this process named ``eskin-port``):
    its seconds waiting for a processor while runnable so far, and its wake-ups
    (``/proc/self/task/*/schedstat``, Linux); (0, 0) without one."""
    best = (0, 0.0, 0)
    for tid in os.listdir("/proc/self/task"):
        try:
            if Path(f"/proc/self/task/{tid}/comm").read_text().strip() != "eskin-port":
                continue
            _, wait, n = Path(f"/proc/self/task/{tid}/schedstat").read_text().split()
        except (OSError, ValueError):
            continue
        best = max(best, (int(tid), int(wait) / 1e9, int(n)))
    return best[1], best[2]


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


def run(model: Path, replay: Path, speed: float, page: str, browser: Browser,
        args: argparse.Namespace, reading: str = "thread") -> dict:
    """One run. ``page``: "none" (the browser idle, no page served), "open" (the page served,
    opened in a tab and loaded before the stream starts), "opening" (the page served, opened in
    a tab at ``args.open_at`` of the stream's expected duration), "blank" (no page served, a
    blank tab opened as in "opening"), "launch" (the page served, a
    second chromium started on it; the stream starts once the page has connected: what is
    measured is the browser's own start-up). ``reading``: "thread" (the listener as shipped:
    its reading thread, real-time where allowed), "ordinary" (that thread under the ordinary
    policy) or "loop" (the baseline listener that reads the port in its own loop)."""
    sim, pty = start_sim(replay, "--model", model, "--speed", speed, "--tick", 10,
                         "--wait-start", fifo=args.sim_fifo)
    server = tab = opener = launched = None
    cpu0 = 0.0
    state = LiveState(pty) if page not in ("none", "blank") else None
    try:
        if state is not None:
            rate = {} if args.tick_hz is None else {"tick_hz": args.tick_hz}
            server = WebServer(state, "127.0.0.1", 0, **rate).start()
        if page in ("open", "launch"):
            if page == "launch":
                launched = Browser(args.nice, not args.same_group, server.url, False)
            else:
                tab = browser.open(server.url)
            deadline = time.monotonic() + 60
            while server.clients == 0:  # the page has loaded and holds its WebSocket
                if time.monotonic() > deadline:
                    sys.exit("bench_web.py: the page did not connect within 60 s")
                time.sleep(0.05)
            if page == "open":
                browser.quiet()  # the page has drawn its first state
            else:
                time.sleep(0.5)  # as a user who starts the stream just after the page shows
        cpu0 = server.cpu_s if server is not None else 0.0
        browser0 = browser.cpu() + (launched.cpu() if launched is not None else 0.0)
        load0 = os.getloadavg()[0]
        queue = {"loop": {"read_queue_bytes": 0}, "ordinary": {"reader_priority": 0},
                 "thread": {}}[reading]
        with LinkListener(pty, model=model, replay=replay, stats_interval=0.25, **queue) as link:
            t_cpu, t_wall = time.thread_time(), time.perf_counter()
            wait0, wakes0 = reader_schedstat()
            if page in ("opening", "blank"):
                opened: list[str] = []
                url = "about:blank" if server is None else server.url
                opener = threading.Timer(args.open_at * args.seconds / speed,
                                         lambda: opened.append(browser.open(url)))
                opener.start()
            events = link.events(until_eof=True, duration=600)
            if state is not None:
                events = state.observed(events, lambda: link.stats)
            holes = []  # (seconds into the run, samples lost) of the first holes
            for ev in events:
                if isinstance(ev, DataBlock) and ev.lost_before and len(holes) < 4:
                    holes.append((round(time.perf_counter() - t_wall, 2), ev.lost_before))
            cpu, wall = time.thread_time() - t_cpu, time.perf_counter() - t_wall
            wait1, wakes1 = reader_schedstat()
            stats = link.stats
            backlog, realtime = link.port.reader_peak, link.port.reader_realtime
        out = {"speed": speed, "page": page, "reading": reading, "realtime": realtime,
               "samples": stats.samples,
               "lost": stats.lost_samples, "dropped": stats.controller_dropped_samples,
               "pacing_p99_us": stats.controller_pacing_p99_us,
               "wall_s": wall, "listener_cpu_s": cpu, "holes": holes,
               "reader_wait_ms": 1000 * (wait1 - wait0), "reader_wakes": wakes1 - wakes0,
               "backlog_kib": backlog / 1024, "load": (load0, os.getloadavg()[0]),
               "browser_cpu_s": browser.cpu() - browser0
               + (launched.cpu() if launched is not None else 0.0)}
        if opener is not None:
            opener.join()
            tab = opened[0] if opened else None
        if server is not None and state is not None:
            clients = server.clients
            server.stop()  # its thread's CPU time is final once it has ended
            out.update(server_cpu_s=server.cpu_s - cpu0, clients=clients,
                       blocks_skipped=state.blocks_dropped, frames_dropped=server.frames_dropped)
        return out
    finally:
        if opener is not None:
            opener.join()
        if server is not None:
            server.stop()
        if tab is not None:
            browser.close(tab)
            browser.quiet()
        if launched is not None:
            launched.stop()
        sim.terminate()
        sim.communicate(timeout=30)


READINGS = {"thread": "", "ordinary": " (ordinary reader)", "loop": " (loop reads)"}
CASES = {"none": "no page", "open": "page open", "opening": "page opened",
         "blank": "blank tab opened", "launch": "browser launched"}


def _case(r: dict) -> str:
    return CASES[r["page"]] + READINGS[r["reading"]]


def _line(r: dict) -> str:
    extra = ""
    if r["page"] not in ("none", "blank"):
        extra = (f" server cpu {r['server_cpu_s']:.2f} s = "
                 f"{r['server_cpu_s'] / r['listener_cpu_s']:.3f} x listener, "
                 f"{1000 * r['server_cpu_s'] / (r['samples'] / 3000):.1f} ms per second of "
                 f"stream; "
                 f"display blocks skipped {r['blocks_skipped']}")
    return (f"speed {r['speed']:g} {_case(r):<24}: samples {r['samples']} lost {r['lost']} "
            f"dropped {r['dropped']} (simulator pacing p99 {r['pacing_p99_us']:.0f} us) wall "
            f"{r['wall_s']:.1f} s listener cpu {r['listener_cpu_s']:.2f} s read backlog peak "
            f"{r['backlog_kib']:.0f} KiB{' (real-time reader)' if r['realtime'] else ''}, "
            f"the reader waited for a processor {r['reader_wait_ms']:.1f} ms over "
            f"{r['reader_wakes']} wake-ups; "
            f"load average {r['load'][0]:.1f} -> "
            f"{r['load'][1]:.1f}; chromium cpu {r['browser_cpu_s']:.2f} s{extra}"
            + (f"; first holes (s into the run, samples) {r['holes']}" if r["holes"] else ""))


def _summary(rows: list[dict]) -> None:
    print("\nsummary (per speed: every run, in the order run):")
    for s, reading in sorted({(r["speed"], r["reading"]) for r in rows}):
        runs = [r for r in rows if r["speed"] == s and r["reading"] == reading]
        rt = {r["realtime"] for r in runs}
        who = {"loop": "the loop reads the port",
               "ordinary": "a reading thread under the ordinary policy",
               "thread": "a reading thread" + (", real-time" if rt == {True} else
                                               ", under the ordinary policy" if rt == {False}
                                               else ", real-time in some runs")}[reading]
        loads = [x for r in runs for x in r["load"]]
        print(f"  speed {s:g}, {who}, load average {min(loads):.1f}-{max(loads):.1f}, read "
              f"backlog peak {max(r['backlog_kib'] for r in runs):.0f} KiB:")
        for case, name in CASES.items():
            b = [r for r in runs if r["page"] == case]
            if not b:
                continue
            line = (f"    {name:<16} lost {[r['lost'] for r in b]}; reader's run-queue wait "
                    f"{[round(r['reader_wait_ms'], 1) for r in b]} ms; listener CPU "
                    f"{sum(r['listener_cpu_s'] for r in b) / len(b):.2f} s; chromium CPU "
                    f"{[round(r['browser_cpu_s'], 2) for r in b]} s of "
                    f"{[round(r['wall_s'], 1) for r in b]} s")
            if case not in ("none", "blank"):
                ratio = [r["server_cpu_s"] / r["listener_cpu_s"] for r in b]
                core = [r["server_cpu_s"] / r["wall_s"] for r in b]
                per_s = [1000 * r["server_cpu_s"] / (r["samples"] / 3000) for r in b]
                line += (f"; server CPU / listener CPU {min(ratio):.3f}-{max(ratio):.3f}, "
                         f"{100 * min(core):.1f}-{100 * max(core):.1f} % of a core, "
                         f"{min(per_s):.1f}-{max(per_s):.1f} ms per second of stream")
            if s == 0:
                line += f"; throughput {max(r['samples'] / r['wall_s'] for r in b) / 3000:.0f}x"
            print(line)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0,
                    help="seconds of signal in the replay (recordings of 1 s and their gaps)")
    ap.add_argument("--speeds", default="0,1,5,10")
    ap.add_argument("--repeat", type=int, default=2,
                    help="rounds per speed (each case once, in turn: forwards, then backwards)")
    ap.add_argument("--cases", default="none,open,opening",
                    help="none: no page; open: the page loaded before the stream; opening: "
                         "the page opened during the stream; blank: no page served, a blank "
                         "tab opened during the stream; launch: a second chromium started on "
                         "the page as the stream starts")
    ap.add_argument("--open-at", type=float, default=0.25,
                    help="'opening': the fraction of the stream's duration at which the tab opens")
    ap.add_argument("--nice", type=int, default=0,
                    help="run chromium under `nice -n N`, its autogroup too (Linux; "
                         "default 0: the same priority as every program)")
    ap.add_argument("--sim-fifo", type=int, default=10 if os.geteuid() == 0 else 0,
                    help="run eskin-fw-sim under SCHED_FIFO at priority N (`chrt -f N`; default "
                         "10 as root, else 0: not): it stands for a controller with a "
                         "processor of its own")
    ap.add_argument("--same-group", action="store_true",
                    help="start chromium in the benchmark's scheduling group (by default it "
                         "calls setsid: a group of its own, as a browser the user opens has)")
    ap.add_argument("--baseline", action="store_true",
                    help="also run the listener that reads the port in its own loop, without "
                         "the reading thread (LinkListener(read_queue_bytes=0)), in turn")
    ap.add_argument("--tick-hz", type=float, default=None,
                    help="display frames a second (default: the server's)")
    ap.add_argument("--ordinary-reader", action="store_true",
                    help="also run the listener with its reading thread under the ordinary "
                         "scheduling policy (LinkListener(reader_priority=0)), in turn")
    args = ap.parse_args()
    readings = ["thread", *(["ordinary"] if args.ordinary_reader else []),
                *(["loop"] if args.baseline else [])]
    cases = [c for c in args.cases.split(",") if c]
    if not cases or any(c not in CASES for c in cases):
        sys.exit(f"bench_web.py: --cases {args.cases}: expected some of {','.join(CASES)}")
    folder = Path(tempfile.mkdtemp(prefix="bench-web-"))
    model, replay = make_case(folder, recordings=max(1, int(args.seconds / 1.4)))
    t0 = time.monotonic()
    browser = Browser(args.nice, not args.same_group)
    print(f"replay: {replay} ({args.seconds:g} s of signal, 4x4 taxels, 3000 samples/s); "
          f"host model {model.name}; {os.cpu_count()} cores; chromium started "
          f"{time.monotonic() - t0:.1f} s before the first run, "
          f"{'in this scheduling group' if args.same_group else 'in a group of its own'}"
          f"{f' under nice -n {args.nice}' if args.nice else ''}; eskin-fw-sim in a group "
          f"of its own{f' under chrt -f {args.sim_fifo}' if args.sim_fifo else ''}; display "
          f"{args.tick_hz or 'at the server default'} frames/s", flush=True)
    rows = []
    try:
        for speed in (float(s) for s in args.speeds.split(",")):
            for k in range(args.repeat):
                for reading in readings:
                    for page in (cases if k % 2 == 0 else cases[::-1]):
                        r = run(model, replay, speed, page, browser, args, reading)
                        rows.append(r)
                        print(_line(r), flush=True)
    finally:
        browser.stop()
    _summary(rows)
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

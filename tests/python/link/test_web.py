"""The live page's server (eskin.link.web): its state and decimation, the address rules, and
the server itself on a real socket (HTTP and WebSocket through aiohttp's client). The page in a
real browser against a real stream: test_web_browser.py."""

from __future__ import annotations

import asyncio
import json
import socket
import threading
import urllib.error
import urllib.request

import numpy as np
import pytest
from waiting import wait_until
from typer.testing import CliRunner

from eskin.cli import app
from eskin.link.events import DataBlock, Decision, InfoEvent, LinkStats, Stats
from eskin.link.protocol import InfoFrame
from eskin.link.web import LiveState, WebServer, parse_web_address, render_page

RATE = 3000.0


def quiet(first: int, n: int, seed: int = 0) -> DataBlock:
    rng = np.random.default_rng(seed + first)
    return DataBlock(first, rng.normal(1000, 3, size=(n, 4, 4)).round().astype(np.int16))


def decision(onset: int, label: str, index: int, source: str = "controller",
             dont_know: bool = False) -> Decision:
    return Decision(source, onset, onset + 600, label, index, (0.5, -0.2, -0.4), dont_know,
                    onset + 600, 250.0)


def info() -> InfoEvent:
    return InfoEvent(InfoFrame(4, 4, RATE, volts_per_count=1e-4, has_model=True,
                               class_names=("brush", "finger", "washer")))


# --------------------------------------------------------------------------- addresses


@pytest.mark.parametrize("value, expected", [
    ("8765", ("127.0.0.1", 8765)),
    ("127.0.0.1:0", ("127.0.0.1", 0)),
    ("localhost:8000", ("localhost", 8000)),
    ("[::1]:8765", ("::1", 8765)),
    ("127.3.4.5:80", ("127.3.4.5", 80)),
])
def test_loopback_addresses_are_accepted(value, expected):
    assert parse_web_address(value) == expected


@pytest.mark.parametrize("value, words", [
    ("0.0.0.0:8765", "not a loopback address; the page is served to other machines only with "
                     "--web-public"),
    ("192.0.2.7:8765", "--web-public"),
    ("[::]:8765", "--web-public"),
    ("http", "expected [HOST:]PORT"),
    ("127.0.0.1:70000", "port 0..65535"),
    ("127.0.0.1:-1", "expected [HOST:]PORT"),
    (":8765", "the host is empty"),
    ("::1:8765", "in brackets"),
])
def test_bad_or_public_addresses_are_refused_naming_the_value(value, words):
    with pytest.raises(ValueError) as err:
        parse_web_address(value)
    assert str(err.value).startswith(f"--web {value}: ") and words in str(err.value)


def test_public_addresses_need_the_option():
    assert parse_web_address("0.0.0.0:8765", public=True) == ("0.0.0.0", 8765)


def one_error_line(res) -> str:
    lines = [x for x in res.output.splitlines() if x.strip()]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "Traceback" not in res.output
    return lines[0]


def test_listen_refuses_a_public_address_without_the_option(tmp_path):
    # refused before anything opens: the port need not exist
    res = CliRunner().invoke(app, ["listen", str(tmp_path / "tty"), "--web", "0.0.0.0:8765"])
    line = one_error_line(res)
    assert line == ("error: --web 0.0.0.0:8765: 0.0.0.0 is not a loopback address; the page is "
                    "served to other machines only with --web-public")


def test_listen_refuses_a_bad_address_and_a_port_in_use(tmp_path):
    res = CliRunner().invoke(app, ["listen", str(tmp_path / "tty"), "--web", "localhost:http"])
    assert "--web localhost:http: expected [HOST:]PORT" in one_error_line(res)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        res = CliRunner().invoke(app, ["listen", str(tmp_path / "tty"),
                                       "--web", f"127.0.0.1:{port}"])
    assert one_error_line(res) == f"error: --web 127.0.0.1:{port}: address already in use"
    res = CliRunner().invoke(app, ["listen", str(tmp_path / "tty"), "--web", "0",
                                   "--web-grace", "-1"])
    assert "--web-grace -1.0" in one_error_line(res)


# --------------------------------------------------------------------------- state


def test_a_touch_heats_its_taxels_and_the_trace_keeps_its_peak():
    state = LiveState(points_per_tick=16)
    state.observe(info())
    for k in range(30):  # 1 s of quiet
        state.observe(quiet(100 * k, 100))
    state.tick()
    quiet_energy = np.array(state.energy)
    assert quiet_energy.max() < 10
    touch = quiet(3000, 300).samples.astype(np.int32)
    touch[:, 1, 2] += (800 * np.sin(np.arange(300) / 5)).astype(np.int32)
    touch[150, 3, 3] += 2000  # one sample: a decimated trace must still show it
    state.observe(DataBlock(3000, touch.astype(np.int16)))
    frame = state.tick()[-1]
    assert frame["type"] == "frame" and frame["grid"] == [4, 4]
    energy = np.array(frame["energy"]).reshape(4, 4)
    assert np.unravel_index(np.argmax(energy), energy.shape) == (1, 2)
    assert energy[1, 2] > 30 * quiet_energy.max()
    assert len(frame["trace"]) == 16  # at most points_per_tick points, whatever arrived
    assert max(v[15] for _, v in frame["trace"]) > 1900
    assert all(3000 <= s < 3300 for s, _ in frame["trace"])


def test_the_trace_is_bounded_whatever_the_rate():
    state = LiveState(points_per_tick=16)
    for k in range(3000):  # 30000 samples in one display frame
        state.observe(quiet(10 * k, 10))
    (frame,) = state.tick()
    assert len(frame["trace"]) == 16
    assert len(json.dumps(frame)) < 6000


def test_observing_never_waits_display_blocks_are_dropped_when_behind():
    state = LiveState(max_pending_blocks=100)
    for k in range(10_000):
        state.observe(quiet(10 * k, 10))
    for k in range(5):
        state.observe(decision(1000 * k, "brush", 0))
    assert state.blocks_dropped == 9_900
    msgs = state.tick()
    # every decision is kept; only display blocks were dropped
    assert [m["type"] for m in msgs] == ["decision"] * 5 + ["frame"]
    assert msgs[-1]["trace"][0][0] >= 99_000 - 10
    assert state.blocks_dropped == 9_900 and state.blocks_shown == 100


def test_a_new_page_gets_the_current_state_and_escaped_labels():
    state = LiveState("/dev/pts/9")
    state.observe(info())
    state.observe(decision(10, "brush", 0))
    state.observe(decision(10, "<b>x</b>", 1, source="host", dont_know=True))
    state.observe(Stats(LinkStats(frames=12, samples=120, lost_samples=3)))
    state.tick()
    hello = state.hello()
    assert hello["status"] == "live" and hello["info"]["classes"] == ["brush", "finger",
                                                                      "washer"]
    assert [d["label"] for d in hello["decisions"]] == ["brush", "<b>x</b>"]
    assert hello["stats"]["lost_samples"] == 3 and hello["stats"]["frames"] == 12
    html = state.decisions_html()
    assert "&lt;b&gt;x&lt;/b&gt;" in html and "<b>x" not in html
    assert html.index("&lt;b&gt;") < html.index(">brush<")  # newest first
    assert "(don't know)" in html
    page = render_page(state)
    assert "brush" in page and "/dev/pts/9" in page and "grid 4x4" in page


def test_decisions_are_scored_against_the_replay(tmp_path):
    from eskin.data.replay import write_replay_arrays

    recs = [np.zeros((4, 4, 1000), np.int16)] * 3
    rf = write_replay_arrays(tmp_path / "r.eskr", recs, labels=[0, 1, 2],
                             class_names=("brush", "finger", "washer"), gap_s=0.1)
    state = LiveState(replay=rf)
    starts = [int(s) for s in rf.segments["start"]]
    state.observe(decision(starts[0] + 100, "brush", 0))
    state.observe(decision(starts[1] + 100, "washer", 2))
    state.observe(decision(starts[2] + 100, "washer", 2, dont_know=True))
    msgs = state.tick()
    assert [m["decision"]["true"] for m in msgs] == ["brush", "finger", "washer"]
    assert [m["decision"]["right"] for m in msgs] == [True, False, True]
    assert msgs[-1]["accuracy"] == {"controller": {"scored": 3, "right": 2, "dont_know": 1}}


# --------------------------------------------------------------------------- server


def get(url: str, headers: dict | None = None) -> tuple[int, str]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        with e:
            return e.code, e.read().decode()


@pytest.fixture
def server():
    state = LiveState("/dev/pts/9")
    state.observe(info())
    state.observe(decision(30, "finger", 1))
    srv = WebServer(state, "127.0.0.1", 0).start()
    yield srv
    srv.stop()


def test_the_page_is_rendered_with_the_decisions_so_far(server):
    status, page = get(server.url)
    assert status == 200
    assert '<td class="label">finger</td>' in page and "<!--DECISIONS-->" not in page
    status, js = get(server.url + "static/live.js")
    assert status == 200 and "new WebSocket" in js
    status, state = get(server.url + "state.json")
    assert status == 200 and json.loads(state)["decisions"][0]["label"] == "finger"


def test_the_page_answers_loopback_names_only_and_only_reads(server):
    assert get(server.url, {"Host": f"localhost:{server.port}"})[0] == 200
    assert get(server.url, {"Host": f"attacker.example:{server.port}"})[0] == 403
    req = urllib.request.Request(server.url, data=b"x", method="POST")
    with pytest.raises(urllib.error.HTTPError) as err:
        urllib.request.urlopen(req, timeout=10)
    with err.value:
        assert err.value.code == 405


async def ws_messages(url: str, until: str, origin: str | None = None, timeout: float = 10
                      ) -> list[dict]:
    """The messages a page's WebSocket receives, up to the first of type ``until`` (or until
    the server closes it)."""
    import aiohttp

    out: list[dict] = []

    async def read() -> None:
        async with aiohttp.ClientSession() as s:
            headers = {"Origin": origin} if origin else {}
            async with s.ws_connect(url.replace("http", "ws") + "ws", headers=headers) as ws:
                async for msg in ws:
                    out.append(json.loads(msg.data))
                    if out[-1]["type"] == until:
                        return

    await asyncio.wait_for(read(), timeout)
    return out


def test_a_page_gets_the_state_then_the_stream_then_stopped():
    state = LiveState("/dev/pts/9")
    state.observe(info())
    state.observe(decision(30, "finger", 1))
    srv = WebServer(state, "127.0.0.1", 0).start()
    first: list[dict] = []

    def client() -> None:
        first.extend(asyncio.run(ws_messages(srv.url, "stopped")))

    t = threading.Thread(target=client)
    t.start()
    # the listener's side, once the page has its hello: a decision and data, then the stop
    wait_until(lambda: srv.clients > 0)
    state.observe(decision(3000, "washer", 2))
    for k in range(20):
        state.observe(quiet(4000 + 10 * k, 10))
    srv.stop(["host: 1/1 recordings right"], grace_s=0.0)
    t.join(15)
    types = [m["type"] for m in first]
    assert types[0] == "hello" and [d["label"] for d in first[0]["decisions"]] == ["finger"]
    assert "decision" in types and "frame" in types and types[-1] == "stopped"
    assert first[-1]["summary"] == ["host: 1/1 recordings right"]
    assert [m["decision"]["label"] for m in first if m["type"] == "decision"] == ["washer"]


def test_a_page_opened_during_the_grace_period_sees_the_stop_then_the_server_closes():
    state = LiveState("/dev/pts/9")
    state.observe(decision(30, "brush", 0))
    srv = WebServer(state, "127.0.0.1", 0).start()
    stopper = threading.Thread(target=srv.stop, args=(["the end"], 3.0))
    stopper.start()
    wait_until(lambda: state.status == "stopped")
    status, page = get(srv.url)
    assert status == 200 and "stopped: the listener has ended" in page and ">brush<" in page
    msgs = asyncio.run(ws_messages(srv.url, "never"))  # ends when the server closes
    assert msgs[0]["type"] == "hello" and msgs[0]["status"] == "stopped"
    assert msgs[0]["summary"] == ["the end"]
    stopper.join(15)
    assert not stopper.is_alive()
    with pytest.raises(OSError):
        urllib.request.urlopen(srv.url, timeout=2)


def test_a_websocket_from_another_origin_is_refused(server):
    import aiohttp

    with pytest.raises(aiohttp.WSServerHandshakeError):
        asyncio.run(ws_messages(server.url, "hello", origin="http://attacker.example"))
    msgs = asyncio.run(ws_messages(server.url, "hello",
                                   origin=f"http://127.0.0.1:{server.port}"))
    assert msgs[0]["type"] == "hello"

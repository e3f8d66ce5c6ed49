"""eskin.serial_port.SerialPort on a real pseudo-terminal (the master end held by os)."""

from __future__ import annotations

import os
import threading

import pytest

from eskin.link.serial_port import PeerClosedError, SerialPort, SerialPortError


@pytest.fixture
def pty():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)  # the port under test opens the slave by path, like a host would
    yield master, path
    try:
        os.close(master)
    except OSError:
        pass


def test_round_trip_all_byte_values(pty):
    master, path = pty
    with SerialPort(path, baud=115200) as port:
        assert port.path == path and port.baud == 115200 and port.is_open
        data = bytes(range(256)) * 4
        os.write(master, data)
        got = b""
        while len(got) < len(data):
            got += port.read(4096, timeout=1.0)
        assert got == data
        assert port.write(b"\x00\x03\x11hello", timeout=1.0) == 8
        assert os.read(master, 100) == b"\x00\x03\x11hello"
    assert not port.is_open


def _reading_threads() -> list[int]:
    """This process's threads named as the port's reading thread names itself."""
    out = []
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/comm") as f:
                if f.read().strip() == "eskin-port":
                    out.append(int(tid))
        except OSError:  # a thread that has just ended
            pass
    return out


def _may_be_realtime() -> bool:
    """Whether this process may put a thread under SCHED_FIFO at priority 1: CAP_SYS_NICE
    in its effective capabilities, or an RLIMIT_RTPRIO of at least 1."""
    import resource

    with open("/proc/self/status") as f:
        caps = next(int(line.split()[1], 16) for line in f if line.startswith("CapEff:"))
    return bool(caps >> 23 & 1) or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] >= 1


@pytest.mark.parametrize("priority", [0, 1])
def test_reader_thread_runs_real_time_where_the_system_allows_it(pty, priority):
    master, path = pty
    before = set(_reading_threads())
    with SerialPort(path) as port:
        assert port.reader_realtime is False  # no reading thread yet
        port.start_reader(capacity=1 << 16, realtime_priority=priority)
        (tid,) = set(_reading_threads()) - before
        expected = priority > 0 and _may_be_realtime()
        assert port.reader_realtime is expected
        policy = os.sched_getscheduler(tid)
        assert policy == (os.SCHED_FIFO if expected else os.SCHED_OTHER)
        assert os.sched_getparam(tid).sched_priority == (priority if expected else 0)
        os.write(master, b"\x01\x02\x03")  # and it reads as the ordinary one does
        got = b""
        while len(got) < 3:
            got += port.read(16, timeout=1.0)
        assert got == b"\x01\x02\x03"


def test_timeout_is_silence_not_closure(pty):
    master, path = pty
    with SerialPort(path) as port:
        assert port.read(10, timeout=0.02) == b""
        assert port.read_nonblocking() == b""
        os.write(master, b"abc")
        assert port.read_exact(5, timeout=0.05) == b"abc"
        os.write(master, b"xyz")
        assert port.read(2, timeout=1.0) == b"xy"
        assert port.in_waiting == 1
        port.flush(output=False)
        assert port.in_waiting == 0


def test_closed_peer_raises(pty):
    master, path = pty
    port = SerialPort(path)
    os.close(master)
    with pytest.raises(PeerClosedError, match="hung up"):
        port.read(10, timeout=1.0)
    with pytest.raises(PeerClosedError):
        port.write(b"x", timeout=0.1)
    port.close()


def test_blocking_read_releases_the_gil(pty):
    master, path = pty
    with SerialPort(path) as port:
        result: list[bytes] = []
        t = threading.Thread(target=lambda: result.append(port.read(10, timeout=5.0)))
        t.start()
        # this thread runs Python while the other waits inside the core
        total = sum(range(10000))
        os.write(master, b"ping")
        t.join(timeout=5.0)
        assert total > 0 and result == [b"ping"]


def test_open_errors_name_the_port():
    with pytest.raises(SerialPortError, match="/no/such/tty") as err:
        SerialPort("/no/such/tty")
    assert err.value.status == "open_failed"
    with pytest.raises(SerialPortError, match="not_a_tty"):
        SerialPort("/dev/null")


def test_bad_baud_and_timeout(pty):
    _, path = pty
    with pytest.raises(SerialPortError, match="baud"):
        SerialPort(path, baud=1234)
    with SerialPort(path) as port, pytest.raises(ValueError, match="timeout"):
        port.read(1, timeout=-1)


def test_reader_thread_empties_the_pty_while_nobody_reads(pty):
    master, path = pty
    with SerialPort(path) as port:
        port.start_reader(capacity=1 << 20)
        port.start_reader(capacity=1 << 20)  # once per port: a second call changes nothing
        data = bytes(range(251)) * 1200  # 301 KB: a pty holds about 20 KB
        view = memoryview(data)
        while view:  # a blocking write completes only because the reader takes it all
            view = view[os.write(master, view):]
        got = b""
        while len(got) < len(data):
            got += port.read(65536, timeout=1.0)
        assert got == data
        assert port.reader_peak > 20000 and port.reader_overflow == 0
        assert port.read(10, timeout=0.01) == b"" and port.read_nonblocking() == b""
        with pytest.raises(SerialPortError, match="start_reader"):
            port.read_exact(4, timeout=0.01)
        os.close(master)
        with pytest.raises(PeerClosedError, match=path):
            for _ in range(20):
                port.read(4096, timeout=1.0)
    assert not port.is_open

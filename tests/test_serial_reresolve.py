"""A silent open port whose path now names another node is given up and reopened.

The configured device is often a name, not the node: ``/dev/serial0``, a udev
``/dev/tfluna-front``, a ``/dev/serial/by-id/...`` link. Here the name is a symlink in
``tmp_path`` and the nodes are two virtual sensors on real pseudo-terminals (pty A and
pty B, ``lunad.sim.pty_device``), read through pyserial as a UART is. Sensor A goes
silent without hanging up, the link is re-pointed at B, and B's readings (told from
A's by their distance) must arrive within a bounded time. Every wait is bounded.
"""

from __future__ import annotations

import logging
import os
import statistics
import time
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.errors import SourceLostError
from lunad.daemon.sources.serial import PATH_CHECK_S, SerialSource
from lunad.protocol.client import Subscriber
from lunad.protocol.frame import Frame
from lunad.protocol.messages import Message, RangeMessage
from lunad.protocol.parser import FrameParser
from lunad.sim.physics import Truth
from lunad.sim.pty_device import PtyDevice

A_M = 1.0  # sensor A's target distance, metres
B_M = 4.0  # sensor B's: a reading within NEAR_M of one of them says which sensor sent it
NEAR_M = 0.5
FIRST_FRAMES_S = 5.0
"""How long a test waits for a streaming sensor's frames (about 10 ms here)."""
GIVE_UP_S = PATH_CHECK_S + 3.0
"""How long a silent port behind a moved link may take to be given up: one check
interval, plus slack for a loaded machine."""


def point(link: Path, target: str) -> None:
    """Make ``link`` a symlink to ``target`` in one step, as udev replaces a link."""
    tmp = link.with_name(f".{link.name}.tmp")
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(target)
    os.replace(tmp, link)


def distance(src: SerialSource, timeout_s: float = FIRST_FRAMES_S, frames: int = 5) -> float:
    """The median distance of the next ``frames`` frames the source reads, metres."""
    parser = FrameParser()
    got: list[float] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < frames:
        left = deadline - time.monotonic()
        assert left > 0, f"{len(got)} of {frames} frames within {timeout_s} s"
        chunk = src.read(min(left, 0.5))
        if chunk is None:
            continue
        for item in parser.feed(chunk.data, chunk.t_mono_ns):
            if isinstance(item, Frame) and item.distance_m is not None:
                got.append(item.distance_m)
    return statistics.median(got)


def drain(src: SerialSource) -> None:
    """Read until the port has been silent for 0.2 s (at most 5 s)."""
    deadline = time.monotonic() + 5.0
    while src.read(0.2) is not None:
        assert time.monotonic() < deadline, "the sensor did not go silent"


def serial_records(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name == "lunad.serial"]


@pytest.fixture
def two_sensors(
    tmp_path: Path, device: Callable[..., PtyDevice]
) -> tuple[PtyDevice, PtyDevice, Path]:
    """Sensor A and sensor B streaming at 100 Hz, and ``tmp_path/tfluna`` pointing at A."""
    a = device(link=tmp_path / "a", truth=Truth(A_M), rate_hz=100)
    b = device(link=tmp_path / "b", truth=Truth(B_M), rate_hz=100)
    link = tmp_path / "tfluna"
    point(link, a.slave_name)
    return a, b, link


def test_a_silent_port_whose_link_moved_is_closed_and_the_link_reopened(
    two_sensors: tuple[PtyDevice, PtyDevice, Path], caplog: pytest.LogCaptureFixture
) -> None:
    a, b, link = two_sensors
    caplog.set_level(logging.INFO, logger="lunad.serial")
    src = SerialSource(str(link))
    try:
        assert abs(distance(src) - A_M) < NEAR_M
        a.pause(3600)  # silent, but the pty stays open: no hang-up tells the reader
        drain(src)
        point(link, b.slave_name)
        t0 = time.monotonic()
        with pytest.raises(SourceLostError, match="now resolves to") as lost:
            while time.monotonic() - t0 < GIVE_UP_S:
                src.read(0.2)
        given_up_s = time.monotonic() - t0
    finally:
        src.close()
    print(f"silent port behind a moved link given up after {given_up_s:.2f} s")
    assert b.slave_name in str(lost.value) and a.slave_name in str(lost.value)
    records = serial_records(caplog)
    assert [r.levelno for r in records] == [logging.INFO], records
    line = records[0].getMessage()
    assert a.slave_name in line and b.slave_name in line and str(link) in line

    # The old node was closed then and there: its exclusive lock is free again.
    SerialSource(a.slave_name).close()

    # Reopened from the configured path, as the daemon does after the error: sensor B.
    t0 = time.monotonic()
    again = SerialSource(str(link))
    try:
        assert abs(distance(again) - B_M) < NEAR_M
    finally:
        again.close()
    assert time.monotonic() - t0 < FIRST_FRAMES_S


def test_a_silent_port_whose_path_is_gone_is_lost(
    two_sensors: tuple[PtyDevice, PtyDevice, Path], caplog: pytest.LogCaptureFixture
) -> None:
    a, _, link = two_sensors
    caplog.set_level(logging.INFO, logger="lunad.serial")
    src = SerialSource(str(link))
    try:
        assert abs(distance(src) - A_M) < NEAR_M
        a.pause(3600)
        drain(src)
        link.unlink()
        t0 = time.monotonic()
        with pytest.raises(SourceLostError, match="no longer exists"):
            while time.monotonic() - t0 < GIVE_UP_S:
                src.read(0.2)
    finally:
        src.close()
    records = serial_records(caplog)
    assert [r.levelno for r in records] == [logging.INFO], records
    assert a.slave_name in records[0].getMessage()


def test_a_silent_port_its_path_still_names_stays_open(
    two_sensors: tuple[PtyDevice, PtyDevice, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """No false alarm: a sensor that pauses behind an unchanged link (rewritten to the
    same target, as a udev 'change' event does) keeps its port, and its frames come
    back on it."""
    a, _, link = two_sensors
    caplog.set_level(logging.INFO, logger="lunad.serial")
    src = SerialSource(str(link))
    try:
        assert abs(distance(src) - A_M) < NEAR_M
        a.pause(3600)
        drain(src)
        point(link, a.slave_name)  # a new link, the same node
        silent_until = time.monotonic() + 2.5 * PATH_CHECK_S  # two checks or more
        while time.monotonic() < silent_until:
            assert src.read(0.2) is None
        a.pause(0)
        assert abs(distance(src) - A_M) < NEAR_M
    finally:
        src.close()
    assert serial_records(caplog) == []


def test_the_path_is_checked_only_when_silent_and_at_most_once_a_second(
    two_sensors: tuple[PtyDevice, PtyDevice, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check costs nothing per frame: no ``stat`` of the path while bytes flow,
    and at most one a second while a silent port times out 100 reads a second."""
    a, _, link = two_sensors
    stat = os.stat
    checks: list[float] = []

    def counting_stat(path: Any, *args: Any, **kw: Any) -> os.stat_result:
        if os.fspath(path) == str(link):
            checks.append(time.monotonic())
        return stat(path, *args, **kw)

    src = SerialSource(str(link))
    try:
        monkeypatch.setattr(os, "stat", counting_stat)
        streamed = 0
        deadline = time.monotonic() + 10.0
        while streamed < 100:  # 1 s of frames, each read waking for what came
            assert time.monotonic() < deadline, f"{streamed} reads of frames in 10 s"
            if src.read(5.0) is not None:
                streamed += 1
        assert checks == [], "the path was looked at while frames arrived"
        a.pause(3600)
        drain(src)
        checks.clear()
        t0 = time.monotonic()
        timeouts = 0
        while time.monotonic() - t0 < 2.5 * PATH_CHECK_S:
            assert src.read(0.01) is None
            timeouts += 1
        monkeypatch.undo()
    finally:
        src.close()
    assert timeouts > 50
    assert 1 <= len(checks) <= 3, f"{len(checks)} checks over {timeouts} silent reads"
    gaps = [later - earlier for earlier, later in pairwise(checks)]
    assert all(gap >= 0.9 * PATH_CHECK_S for gap in gaps), gaps


def test_the_daemon_follows_a_moved_link_to_the_sensor_behind_it(
    tmp_path: Path,
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    subscriber: Subscriber,
    helpers: Any,
) -> None:
    """End to end with ``lunad serve``: A goes silent (health says ``waiting``), the link
    moves to B, and B's readings are published. B starts with its output off, so they
    come only if the daemon reopened the port as after an unplug and configured the
    sensor behind it (that is what turns the output on)."""
    a = device(link=tmp_path / "a", truth=Truth(A_M), rate_hz=100, output_enabled=False)
    link = tmp_path / "tfluna"
    point(link, a.slave_name)
    d = start_daemon("--device", str(link), "--publish", endpoint, "--name", "t1")

    def reads(metres: float) -> Callable[[Message], bool]:
        return lambda m: (
            isinstance(m, RangeMessage) and m.raw_m is not None and abs(m.raw_m - metres) < NEAR_M
        )

    helpers.wait_for(subscriber, reads(A_M), timeout=helpers.startup_s)
    a.pause(3600)
    helpers.wait_for(subscriber, helpers.health_state("waiting"), timeout=5)
    b = device(link=tmp_path / "b", truth=Truth(B_M), rate_hz=100, output_enabled=False)
    point(link, b.slave_name)
    t0 = time.monotonic()
    helpers.wait_for(subscriber, reads(B_M), timeout=GIVE_UP_S + 5.0)
    print(f"readings from the sensor behind the moved link after {time.monotonic() - t0:.2f} s")
    assert d.proc.poll() is None
    moved = f"{link} now resolves to {b.slave_name}, not {a.slave_name}"
    info = [line for line in d.log.splitlines() if line.startswith("INFO lunad.serial")]
    assert len(info) == 1 and moved in info[0], d.log

"""Record and replay through the whole daemon: `serve --record`, `lunad record`, then
`serve --replay` publishes the same readings the live run did; and the simulated I2C
bus through the whole daemon."""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lunad.daemon.sources.recording import Replay
from lunad.protocol.client import Subscriber
from lunad.protocol.messages import HealthMessage, RangeMessage
from lunad.sim.physics import Truth
from lunad.sim.pty_device import PtyDevice
from lunad.sim.virtual_sensor import SERIAL_NUMBER


def ranges_until_quiet(sub: Subscriber, quiet_s: float = 1.0) -> list[RangeMessage]:
    out = []
    while (m := sub.recv(timeout_s=quiet_s)) is not None:
        if isinstance(m, RangeMessage):
            out.append(m)
    return out


def until_stopped(
    endpoint: str,
    timeout_s: float = 20.0,
    on_range: Callable[[list[RangeMessage]], None] | None = None,
) -> tuple[list[RangeMessage], HealthMessage | None]:
    """Every range message from ``endpoint`` until a ``stopped`` health message (or
    ``timeout_s``), and the last health message; ``on_range`` is called with the range
    messages so far at each one."""
    ranges: list[RangeMessage] = []
    last: HealthMessage | None = None
    with Subscriber(endpoint) as sub:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and (last is None or last.state != "stopped"):
            msg = sub.recv(timeout_s=1.0)
            if isinstance(msg, RangeMessage):
                ranges.append(msg)
                if on_range is not None:
                    on_range(ranges)
            elif isinstance(msg, HealthMessage):
                last = msg
    return ranges, last


def test_a_replay_with_publish_hz_sends_its_last_frames(
    start_daemon: Any, endpoint: str, tmp_path: Path
) -> None:
    """With ``--publish-hz``, the frames folded since the last message at the end of a
    replay were never sent (the last 17 of 493 at 10 Hz; at 0.5 Hz only the first
    frame's message went out) while health said every frame was published. The last
    estimate goes out before ``stopped``, and the messages' ``frames`` add up."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    rec = tmp_path / "folded.lunarec"
    five = b"".join(encode_frame(150, 3000, 2368) for _ in range(5))
    with Recorder(rec, source_desc="test", frame_rate_hz=250) as r:
        for k in range(61):  # 305 frames, 1.22 s
            r(Chunk(five, 10**12 + (k + 1) * 20_000_000))
    for hz in ("10", "0.5"):
        d = start_daemon(
            "--replay", str(rec), "--speed", "max", "--publish-hz", hz, "--publish", endpoint
        )
        ranges, last = until_stopped(endpoint)
        assert last is not None and last.state == "stopped", d.log
        assert ranges[-1].seq == 304 and sum(m.frames for m in ranges) == 305, (hz, d.log)
        assert d.proc.wait(timeout=15) == 0


def test_a_sighup_that_changes_only_the_speed_goes_on_where_the_replay_is(
    start_daemon: Any, endpoint: str, tmp_path: Path
) -> None:
    """A SIGHUP that changed a replay's ``speed`` started the file again in the same
    ``run``: 710 readings from a 493-frame file, ``t_mono_ns`` stepping back with no gap
    in ``seq``. The new speed now paces the rest of the file: each frame once, in order."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    rec = tmp_path / "slow.lunarec"
    with Recorder(rec, source_desc="test", frame_rate_hz=250) as r:
        for k in range(400):  # 2000 frames, 8 s at 1x
            r(Chunk(encode_frame(100 + k % 50, 3000, 2368) * 5, 10**12 + (k + 1) * 20_000_000))
    cfg = tmp_path / "replay.toml"
    cfg.write_text(f'[source]\nkind = "replay"\npath = "{rec}"\nspeed = 1.0\n')
    d = start_daemon("--config", str(cfg), "--publish", endpoint)

    def faster(ranges: list[RangeMessage]) -> None:
        if len(ranges) == 100:  # 0.4 s in: four times as fast from here
            cfg.write_text(cfg.read_text().replace("speed = 1.0", "speed = 4.0"))
            d.proc.send_signal(signal.SIGHUP)

    ranges, last = until_stopped(endpoint, 30.0, faster)
    assert last is not None and last.state == "stopped", d.log
    assert d.proc.wait(timeout=15) == 0, d.log
    assert f"SIGHUP: replay {rec} at 4x" in d.log and "changed: source" in d.log, d.log
    assert [m.seq for m in ranges] == list(range(2000)), d.log
    assert [m.t_mono_ns for m in ranges] == sorted(m.t_mono_ns for m in ranges)
    assert d.log.count(f"opened replay {rec}") == 1, d.log


def comparable(msgs: list[RangeMessage]) -> list[dict[str, Any]]:
    # a run per daemon start; a message a subscriber got from the cache on joining says so
    return [m.model_dump(exclude={"t_unix_ns", "run", "cached", "age_ms"}) for m in msgs]


@pytest.mark.parametrize("publish_hz", [None, "50"])
def test_replay_publishes_what_the_live_run_did(
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    tmp_path: Path,
    helpers: Any,
    publish_hz: str | None,
) -> None:
    rec = tmp_path / "live.lunarec"
    dev = device(
        rate_hz=250,
        output_enabled=False,
        garbage_rate=0.05,
        corrupt_rate=0.02,
        truth=Truth(1.5, 0.3, 30.0, 20000.0),
        seed=7,
    )
    live = start_daemon(
        "--device",
        dev.path,
        "--publish",
        endpoint,
        "--rate",
        "250",
        "--record",
        str(rec),
        "--name",
        "r",
        *(("--publish-hz", publish_hz) if publish_hz else ()),
    )
    with Subscriber(endpoint) as sub:
        first = helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        time.sleep(1.5)
        dev.pause(3600)
        time.sleep(0.1)  # a frame the device was writing when paused
        live_msgs = [first, *helpers.ranges_through(sub, dev.frames_sent - 1)]
        assert ranges_until_quiet(sub, quiet_s=0.5) == []
    assert live.stop() == 0
    s0 = live_msgs[0].seq  # the live subscriber joined a little late (ZeroMQ slow joiner)
    if publish_hz:
        assert len(live_msgs) < dev.frames_sent - s0  # folded
    else:
        assert [m.seq for m in live_msgs] == list(range(s0, s0 + len(live_msgs)))
    with Replay(rec) as r:
        assert r.header.source_desc.startswith("serial")
        assert sum(len(c.data) for c in r) > 9 * len(live_msgs)

    ep2 = f"ipc://{tmp_path}/replay.sock"
    replay = start_daemon(
        *("--replay", str(rec), "--speed", "max", "--publish", ep2, "--name", "r"),
        *(("--publish-hz", publish_hz) if publish_hz else ()),
    )
    with Subscriber(ep2) as sub:
        if publish_hz:  # which seq comes last depends on the folding: read until it ends
            first = helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
            replayed = [first, *ranges_until_quiet(sub, quiet_s=3.0)]
        else:
            replayed = helpers.ranges_through(sub, live_msgs[-1].seq)
        assert replay.proc.wait(timeout=15) == 0  # the end of the recording ends the daemon
    if not publish_hz:
        assert [m.seq for m in replayed] == list(range(len(replayed)))  # replay waited for us
    replayed = [m for m in replayed if m.seq >= s0]
    # no --rate given: the recording's 250 Hz times the frames, and the sensor's
    # recorded answer to the live run's rate command is no surprise
    assert "its sensor sent 250 frames a second" in replay.log
    assert "asked for" not in replay.log and "frame rate 250 Hz" in replay.log
    if publish_hz:
        # Every frame is filtered alike, so a message of the same frame is the same
        # message. Which frames are sent is decided by the reads' times, as recorded, by
        # the rule the live run followed; a live message sent on its timer with nothing
        # new read (the last before a stall, or before bytes the pty delivered late) is
        # one the replay may not send, and folds into its next message, whose ``frames``
        # then counts both: 76-77 of 76-77 live messages were replayed on a quiet host
        # and under three busy loops, and one of them missed once in about ten runs.
        live_by_seq = {m.seq: m for m in live_msgs}
        replayed_seqs = {m.seq for m in replayed}
        common = [m for m in replayed if m.seq in live_by_seq]
        for m in common:
            folded = [
                live_by_seq[s].frames
                for s in live_by_seq
                if m.seq - m.frames < s < m.seq and s not in replayed_seqs
            ]
            assert m.frames == live_by_seq[m.seq].frames + sum(folded), m.seq
        assert [c | {"frames": 0} for c in comparable(common)] == [
            c | {"frames": 0} for c in comparable([live_by_seq[m.seq] for m in common])
        ]
        assert len(common) >= 0.75 * len(live_msgs)
    else:
        assert comparable(replayed) == comparable(live_msgs)
    assert any(m.status != "ok" for m in replayed)  # a run with dropouts and filtering in it


def lunad_record(
    helpers: Any, dev: PtyDevice, out: Path, duration_s: float, **run: Any
) -> subprocess.CompletedProcess[str]:
    """``lunad record`` from ``dev`` into ``out`` for ``duration_s`` seconds, to the end."""
    return subprocess.run(
        [*helpers.lunad, "record", "--device", dev.path, "--out", str(out),
         "--duration", f"{duration_s:g}"],
        capture_output=True,
        text=True,
        **run,
    )  # fmt: skip


def test_lunad_record_command(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    dev = device(rate_hz=100, output_enabled=False)
    out = tmp_path / "cmd.lunarec"
    r = lunad_record(helpers, dev, out, 2.0, timeout=30)
    assert r.returncode == 0, r.stderr
    from lunad.protocol import FrameParser

    p = FrameParser()
    with Replay(out) as rp:
        for c in rp:
            p.feed(c.data, c.t_mono_ns)
    assert p.stats.replies >= 3  # version, rate, output echoes: it configured the sensor
    assert 10 <= p.stats.frames <= dev.frames_sent  # 100 Hz for about 2 s, very loosely
    assert p.stats.checksum_errors == 0


def test_lunad_record_reconnects_when_the_start_up_commands_fail(
    tmp_path: Path, helpers: Any
) -> None:
    """A ``socket://`` server (ser2net) that resets each connection at once: the
    start-up commands' write fails. ``lunad record`` must treat that as a lost source,
    as it does a failed read, and retry with backoff; it ended in a traceback, exit 1."""
    import socket
    import struct
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    accepted = []

    def reset_each() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            accepted.append(time.monotonic())
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            conn.close()  # RST: the client's next write fails with ECONNRESET

    threading.Thread(target=reset_each, daemon=True).start()
    out = tmp_path / "reset.lunarec"
    try:
        r = subprocess.run(
            [*helpers.lunad, "record", "--device", f"socket://127.0.0.1:{port}",
             "--out", str(out), "--duration", "3"],
            capture_output=True, text=True, timeout=30,
        )  # fmt: skip
    finally:
        server.close()
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "reconnecting" in r.stderr
    assert 2 <= len(accepted) <= 10, accepted  # retried, with backoff (0.1 s doubling)


def test_replay_of_a_missing_or_bad_file_is_a_config_error(tmp_path: Path, helpers: Any) -> None:
    bad = tmp_path / "bad.lunarec"
    bad.write_bytes(b"not a recording at all")
    for path in (tmp_path / "missing.lunarec", bad):
        r = subprocess.run(
            [*helpers.lunad, "serve", "--replay", str(path)],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert r.returncode == 78, r.stderr
        assert "--replay" in r.stderr and "Traceback" not in r.stderr


def test_simulated_i2c_bus_through_the_daemon(
    start_daemon: Any, endpoint: str, helpers: Any
) -> None:
    d = start_daemon("--bus", "sim", "--publish", endpoint, "--rate", "100", "--name", "i2c")
    with Subscriber(endpoint) as sub:
        helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        msgs: list[RangeMessage] = []
        t_end = time.monotonic() + 10.0
        while len(msgs) < 50 and time.monotonic() < t_end:
            m = sub.recv(timeout_s=0.5)
            if isinstance(m, RangeMessage):
                msgs.append(m)
        h = helpers.wait_for(sub, helpers.health_state("connected"), timeout=3)
    assert len(msgs) == 50
    assert [m.seq for m in msgs] == list(range(msgs[0].seq, msgs[0].seq + len(msgs)))
    assert all(m.raw_m is not None and abs(m.raw_m - 2.0) < 0.2 for m in msgs)
    assert all(30 < m.temp_c < 50 for m in msgs)  # 0.01 degC registers, converted
    # the realistic sensor indoors: usable readings, not the paper's literal daylight
    assert sum(m.status == "ok" for m in msgs) >= 40, [m.reasons for m in msgs][:5]
    assert not any("high_ambient" in m.reasons for m in msgs)
    assert h.firmware == "3.0.9" and h.checksum_errors == 0
    assert h.serial == SERIAL_NUMBER.decode()  # registers 0x10..0x1D, via command 0x12
    assert "opened i2c bus sim address 0x10" in d.log


def test_replay_keeps_sending_health(start_daemon: Any, endpoint: str, tmp_path: Path) -> None:
    """A replay's chunks keep their recorded times, which mean nothing on this machine's
    clock: health comes every second while it plays (timed by the recorded times, it came
    every 2 s or so), says ``waiting`` until the first subscriber, and a last ``stopped``
    one counts every frame."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    rec = tmp_path / "slow.lunarec"
    with Recorder(rec, source_desc="test") as r:
        five = b"".join(encode_frame(200, 1500, 2368) for _ in range(5))
        for k in range(200):  # 4 s of a 250 Hz sensor, five frames a chunk, recorded at t ~ 0
            r(Chunk(five, (k + 1) * 20_000_000))
    start_daemon("--replay", str(rec), "--publish", endpoint)
    while_playing = []
    states = []
    with Subscriber(endpoint) as sub:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            msg = sub.recv(timeout_s=1.0)
            if isinstance(msg, HealthMessage):
                states.append(msg.state)
                if msg.state == "connected" and msg.frames < 1000:
                    while_playing.append(msg.frames)
                if msg.state == "stopped":
                    assert msg.frames == 1000, "the last health counts every frame replayed"
                    break
    assert len(while_playing) >= 3, f"health while the 4 s replay played: {while_playing} frames"
    assert states[0] == "waiting", "a replay waits for its first subscriber: waiting"
    assert "reconnecting" not in states and states[-1] == "stopped", states


@pytest.mark.parametrize("header_hz", [1, 300])
def test_a_replay_times_frames_by_the_rate_they_came_at(
    start_daemon: Any, endpoint: str, tmp_path: Path, header_hz: int
) -> None:
    """Frames that came at 100 Hz, ten a read, under a header that says otherwise: 1 Hz
    (a sensor that ignored ``--rate 1``) or 300 Hz (no TF-Luna runs at it: a header lunad
    did not write). The replay's frame clock follows the recorded reads as the live run's
    did: after them every reading of the still card is published, and the last health
    says 100 Hz. Timed by the 1 Hz header, a read's ten frames would lie 9 s apart, each
    read a clock started again for the filter, and every reading a dropout."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    rec = tmp_path / "deaf.lunarec"
    ten = b"".join(encode_frame(200, 5000, 2368) for _ in range(10))
    with Recorder(rec, source_desc="test", frame_rate_hz=header_hz) as r:
        for k in range(60):  # 6 s
            r(Chunk(ten, 10**12 + (k + 1) * 100_000_000))
    d = start_daemon("--replay", str(rec), "--speed", "max", "--publish", endpoint)
    ranges, last = until_stopped(endpoint)
    assert last is not None and last.state == "stopped", d.log
    assert last.frame_rate_hz == 100.0, d.log
    late = [m.status for m in ranges if m.seq >= 300]  # the last 3 s
    assert len(late) == 300 and set(late) == {"ok"}, (set(late), d.log)
    if header_hz == 1:
        assert "its sensor sends 100 frames a second, not the 1 its recording gives" in d.log
    else:  # not taken: the replay starts from --rate (100), which the frames agree with
        assert "its header gives 300 frames a second, a rate the sensor cannot run at" in d.log


def test_sighup_to_a_missing_recording_keeps_the_replay(
    start_daemon: Any, endpoint: str, tmp_path: Path, helpers: Any
) -> None:
    """Start-up refuses a ``--replay`` path that is missing; a reload to one was taken,
    dropped the replay that worked and sat in ``reconnecting``. Now it is refused too."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder
    from lunad.protocol.frame import encode_frame

    rec = tmp_path / "four_s.lunarec"
    with Recorder(rec, source_desc="test") as r:
        five = b"".join(encode_frame(200, 1500, 2368) for _ in range(5))
        for k in range(200):  # 4 s of a 250 Hz sensor, five frames a chunk
            r(Chunk(five, (k + 1) * 20_000_000))
    cfg = tmp_path / "replay.toml"
    cfg.write_text(f'[source]\nkind = "replay"\npath = "{rec}"\n')
    d = start_daemon("--config", str(cfg), "--publish", endpoint)
    with Subscriber(endpoint) as sub:
        first = helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        cfg.write_text(cfg.read_text().replace(str(rec), str(tmp_path / "missing.lunarec")))
        d.proc.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 10
        while "keeping the running configuration" not in d.log:
            assert time.monotonic() < deadline, d.log
            time.sleep(0.05)
        later = helpers.wait_for(sub, lambda m: helpers.is_range(m) and m.seq > first.seq + 50, 5)
    assert later.seq > first.seq + 50  # the replay went on
    assert "missing.lunarec" in d.log and "configuration reloaded" not in d.log, d.log


def test_a_recording_that_cannot_be_opened_stops_serve_before_it_starts(
    tmp_path: Path, endpoint: str
) -> None:
    """A missing directory, or a file that is not a recording: exit 78 (EX_CONFIG)
    naming the field, nothing bound, the foreign file untouched."""
    foreign = tmp_path / "notes.txt"
    foreign.write_text("hello\n")
    for path, why in ((tmp_path / "no" / "x.lunarec", "No such file"), (foreign, "magic")):
        out = subprocess.run(
            [sys.executable, "-m", "lunad.daemon.cli", "serve", "--device", "loop://",
             "--publish", endpoint, "--record", str(path)],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert out.returncode == 78, out.stderr
        assert "source.record (--record): cannot record to" in out.stderr and why in out.stderr
        assert "Traceback" not in out.stderr
        assert not (tmp_path / "lunad.sock").exists()
    assert foreign.read_text() == "hello\n"


def _file_size_limit(nbytes: int) -> Callable[[], None]:
    """For ``preexec_fn``: files the process writes stop at ``nbytes`` (EFBIG, as a full
    card gives ENOSPC), and no SIGXFSZ kills it for trying."""

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))

    return limit


def test_a_full_disk_ends_the_recording_not_the_daemon(
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    tmp_path: Path,
    helpers: Any,
) -> None:
    """Recording at 100 Hz into a 16 KiB limit fills it in about 6 s; the daemon logs
    it, says it on health, and goes on publishing."""
    rec = tmp_path / "full.lunarec"
    dev = device(rate_hz=100, output_enabled=False)
    d = start_daemon(
        "--device", dev.path, "--publish", endpoint, "--record", str(rec),
        preexec_fn=_file_size_limit(16384),
    )  # fmt: skip
    with Subscriber(endpoint) as sub:
        first = helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        health = helpers.wait_for(
            sub, lambda m: getattr(m, "last_error", None) and "recording" in m.last_error, 30
        )
        assert "recording to" in health.last_error and "stopped" in health.last_error
        after = helpers.wait_for(sub, lambda m: helpers.is_range(m) and m.seq > first.seq + 200, 10)
        assert d.proc.poll() is None
    assert d.stop() == 0
    assert "serving goes on" in d.log and "Traceback" not in d.log
    recorded = b"".join(c.data for c in Replay(rec))
    assert 0 < len(recorded) < 16384 and after.seq > len(recorded) // 9


def test_a_file_being_recorded_is_refused_by_record_and_serve(
    device: Callable[..., PtyDevice], tmp_path: Path, endpoint: str, helpers: Any
) -> None:
    """This test process holds the recording, as a running ``lunad record`` would. A
    second writer used to append beside it, both reporting success while they overwrote
    each other's records; now ``lunad record`` and ``lunad serve --record`` refuse it at
    start with one line and exit 78, and the file is untouched."""
    from lunad.daemon.sources.base import Chunk
    from lunad.daemon.sources.recording import Recorder

    dev = device(rate_hz=100, output_enabled=False)
    rec = tmp_path / "busy.lunarec"
    with Recorder(rec, "the first writer") as holder:
        holder(Chunk(b"first", 1))
        for said in helpers.recording_refused(dev.path, endpoint, rec):
            assert "is being recorded by another process" in said
    assert [c.data for c in Replay(rec)] == [b"first"]


def test_lunad_record_stops_with_one_line_when_the_disk_fills(
    device: Callable[..., PtyDevice], tmp_path: Path, helpers: Any
) -> None:
    """A 4 KiB file size limit (EFBIG, as a full card gives ENOSPC) fills in about 2 s
    at 100 Hz: one line naming the file, exit 74 (EX_IOERR), and every chunk written
    before it replays. It used to end in an OSError traceback, exit 1."""
    dev = device(rate_hz=100, output_enabled=False)
    out = tmp_path / "full.lunarec"
    r = lunad_record(helpers, dev, out, 60, timeout=90, preexec_fn=_file_size_limit(4096))
    assert r.returncode == 74, r.stderr
    assert "Traceback" not in r.stderr
    last = r.stderr.splitlines()[-1]
    assert last.startswith(f"lunad record: writing {out} failed: [Errno 27]"), r.stderr
    kept = int(last.rsplit("(", 1)[1].split()[0])
    with Replay(out) as rp:
        assert len(list(rp)) == kept > 10


def test_sighup_reopens_a_recording_under_the_lock(
    device: Callable[..., PtyDevice],
    start_daemon: Any,
    endpoint: str,
    tmp_path: Path,
    helpers: Any,
) -> None:
    """The recorder's lock must not refuse the daemon's own reloads: one that keeps the
    file keeps its recorder, even under another name (a symlink), and a move to another
    file and back opens each in turn."""
    dev = device(rate_hz=100, output_enabled=False)
    a, b = tmp_path / "a.lunarec", tmp_path / "b.lunarec"
    link = tmp_path / "link.lunarec"
    link.symlink_to(a)
    cfg = tmp_path / "r.toml"

    def config(record: Path, health_s: float) -> str:
        return (
            f'[source]\ndevice = "{dev.path}"\nrecord = "{record}"\n'
            f'[publish]\nendpoint = "{endpoint}"\nhealth_interval_s = {health_s}\n'
        )

    cfg.write_text(config(a, 1.0))
    d = start_daemon("--config", str(cfg))
    with Subscriber(endpoint) as sub:
        helpers.wait_for(sub, helpers.is_range, timeout=helpers.startup_s)
        steps = ((a, 0.5), (b, 0.5), (a, 0.5), (link, 1.0))
        for n, (record, health_s) in enumerate(steps, start=1):
            cfg.write_text(config(record, health_s))
            d.proc.send_signal(signal.SIGHUP)
            deadline = time.monotonic() + 10
            while d.log.count("configuration reloaded") < n:
                assert "keeping the running configuration" not in d.log, d.log
                assert time.monotonic() < deadline, d.log
                time.sleep(0.05)
            after = time.monotonic_ns()
            helpers.wait_for(sub, lambda m, t=after: helpers.is_range(m) and m.t_mono_ns > t, 10)
    assert d.stop() == 0
    assert "being recorded" not in d.log and "Traceback" not in d.log
    assert d.log.count(f"recording every byte read to {a}") == 2
    assert all(sum(len(c.data) for c in Replay(p)) > 0 for p in (a, b))

"""Bench figure 1: numpy decode of a recorded stream (``lunad.protocol.bulk``), in frames
per second, checked frame for frame against the streaming parser."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class BulkResult:
    """Bulk decode of a synthetic recording (frames with garbage between some)."""

    frames: int
    stream_bytes: int
    bulk_fps: float
    streaming_fps: float
    same_as_streaming: bool


def synthetic_stream(n_frames: int, garbage_every: int = 50, seed: int = 0) -> bytes:
    """A recording-like byte stream: ``n_frames`` good frames, a burst of 1-16 random
    bytes before every ``garbage_every``-th one and a corrupted frame now and then."""
    import numpy as np

    rng = np.random.default_rng(seed)
    body = np.empty((n_frames, 9), dtype=np.uint8)
    body[:, 0] = body[:, 1] = 0x59
    dist = rng.integers(20, 800, n_frames, dtype=np.uint16)
    amp = rng.integers(50, 30000, n_frames, dtype=np.uint16)
    temp = np.full(n_frames, round((40.0 + 256.0) * 8.0), dtype=np.uint16)
    fields = np.stack([dist, amp, temp], axis=1).astype("<u2")
    body[:, 2:8] = fields.view(np.uint8).reshape(n_frames, 6)
    body[:, 8] = body[:, :8].sum(axis=1, dtype=np.uint8)
    parts: list[bytes] = []
    step = max(1, garbage_every)
    for start in range(0, n_frames, step):
        junk = rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes()
        block = body[start : start + step].copy()
        if start % (7 * step) == 0 and len(block) > 1:
            block[1, 8] ^= 0x5A  # a bad checksum
        parts.append(junk + block.tobytes())
    return b"".join(parts)


def bench_bulk(n_frames: int = 1_000_000, repeats: int = 5, check: bool = True) -> BulkResult:
    """Decode a synthetic recording with ``decode_bulk``; best of ``repeats``."""
    import time

    from lunad.protocol.bulk import decode_bulk
    from lunad.protocol.frame import Frame
    from lunad.protocol.parser import FrameParser

    data = synthetic_stream(n_frames)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = decode_bulk(data)
        best = min(best, time.perf_counter() - t0)
    frames = len(res.dist)
    n_check = min(len(data), 9 * 200_000)
    t0 = time.perf_counter()
    parsed = FrameParser().feed(data[:n_check], 0)
    streaming = time.perf_counter() - t0
    same = True
    if check:
        part = decode_bulk(data[:n_check])
        got = [(f.dist, f.amp, f.temp_raw) for f in parsed if type(f) is Frame]
        same = got == list(
            zip(part.dist.tolist(), part.amp.tolist(), part.temp_raw.tolist(), strict=True)
        )
    return BulkResult(
        frames=frames,
        stream_bytes=len(data),
        bulk_fps=frames / best,
        streaming_fps=sum(1 for f in parsed if hasattr(f, "dist")) / streaming,
        same_as_streaming=same,
    )

"""Filter evaluation: lunad against baselines it shares no code with, in two worlds.

How this works. For each scenario, world and seed, one stream of readings is drawn
from a sensor physics (no I/O, no pty) and fed frame by frame to four methods:

    raw        the distance the sensor reported, whenever it reported one
    median5    the median of the last 5 readings the sensor's own rule accepts
               (100 <= amp <= 32768, docs/tfluna.md section 4)
    lunad      lunad's RangeFilter.step, the exact code the daemon runs
    oracle     an independent constant-velocity Kalman filter (sim/oracle.py) told
               each reading's true sigma, its process noise the best of
               ``Q_GRID_M2_S3`` for this very run in hindsight; and a lux figure
               read in hindsight (``_hindsight_lux``): the most the readings can tell

and two worlds that lunad is not told about:

    paper      RealisticSensor (physics.py): the paper's law sigma = (sigma0 + k L) / S
    shot       ShotNoiseSensor (shot_noise.py): shot noise, sigma ~ sqrt(S + b L) / S,
               its own amp scale and constants

Metrics, per method (frames where it published an estimate are "published"; "away"
frames are not within ``STEP_SETTLE_S`` after a distance step):

    rmse_m        RMSE of published away estimates, metres
    coverage      published frames / all frames
    two_sigma     share of published estimates within 2 sigma of the truth
    five_sigma    share of published estimates more than 5 sigma off
    bad_frames    published estimates more than BAD_ERROR_M off, not counting the
                  first STEP_GRACE_FRAMES frames after each step
    step_lag      frames from a step until the estimate is first within
                  LAG_ERROR_M of the new distance, counting only frames whose
                  reading the sensor's own rule accepts (a target that reports
                  nothing cannot be followed); the worst step of the run
    lux_ok        share of published lux figures within LUX_REL_TOL or LUX_ABS_TOL_LUX
                  of the truth, on frames where the light has been steady for
                  LUX_SETTLE_S (the lux a filter can know)
    lux_null      share of published frames whose lux_est is null (not observable)

The oracle's lux figure says what lux_ok a filter could reach at all. At each settled
frame it reads c^2 from every reading since the true light was last more than
``HINDSIGHT_LUX_BAND`` of the tolerance away from today's (at most
``HINDSIGHT_LUX_WINDOW_S``): the mean of (d2^2 - 6 q) / (1/S^2 + 4/S1^2 + 1/S2^2) over
the second differences d2 of consecutive readings' errors (the truth subtracted: the
motion known), leaving out readings at an edge (edges.py) and second differences
beyond ``HINDSIGHT_CUT_SIGMAS`` of their true sigma (a spike); it inverts
c = sigma0 + k L with lunad's constants, as lunad does. It knows when the light
changed, the motion and which samples are clean, but uses only readings whose true
noise is at least the 1 cm output step (there Sheppard's q holds; below it the
readings of a still target depend on where it sits between two steps), and is judged
only on such frames: where most readings are quieter than that (a sweep past near
walls) it has fewer samples than lunad and may score lower. Where the noise is well
above the step throughout (cloud_flicker, sun_ramp) and even it is within tolerance
on fewer than ``Targets.lux_ok`` of its frames, the light is not in the readings to
the precision the target asks; check_targets quotes its share beside a lux target
lunad misses. Its lux_null is the share of frames it gives no figure.

and, for lunad, ``mixed_ok``: readings of a beam on two surfaces at an edge
(edges.py: the readings right after each distance step mix the old and the new
surface) that it published ``ok``.

lunad's RMSE is compared with the oracle's and median5's on the frames where both
published (a method that drops the hardest frames must not score better for it).

Beside a 2-sigma coverage outside the band, check_targets quotes the oracle's own
where that is outside the band too: the oracle's sigma comes from the true noise, so
such a run says how far one run's coverage strays by chance. On a still or slow
target the filter's error moves slowly, and a 10-20 s run holds few independent
errors: on seeds 140-159 the oracle is outside the band on 108 of 480 runs (44 below
90 %, 64 above 99 %), lunad on 40 (7 and 33), 24 of them runs where the oracle is too.

This is the only sim module that imports lunad.filters (docs/architecture.md).
"""

from __future__ import annotations

import math
import random
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, fields
from typing import Protocol

from lunad.filters import FilterConfig, RangeFilter, Status
from lunad.sim.edges import edge_view
from lunad.sim.oracle import tuned_oracle
from lunad.sim.physics import AMP_AMBIENT, AMP_WEAK, RawReading, RealisticSensor, Truth
from lunad.sim.scenario import Scenario
from lunad.sim.shot_noise import ShotNoiseSensor

BAD_ERROR_M = 0.3  # a usable output more than 30 cm off is a bad output
STEP_GRACE_FRAMES = 3  # bad outputs in the first three frames of a step are excused
LAG_ERROR_M = 0.15  # a step is followed once the estimate is within 15 cm of it
STEP_SETTLE_S = 0.2  # "away from steps": 0.2 s (50 frames at 250 Hz) after each step
MEDIAN_WINDOW = 5
ORACLE_MAX_COAST_S = 0.1
"""The oracle ends a track after 0.1 s without an accepted reading: coasting for ever
puts its prediction metres off while a target is out of range."""
LUX_REL_TOL = 0.30  # lux within 30 % of the truth ...
LUX_ABS_TOL_LUX = 2000.0  # ... or 2 klux, whichever is larger
LUX_SETTLE_S = 0.5  # the light must have been steady this long (a change is followed in 0.5 s)
HINDSIGHT_LUX_BAND = 0.5
"""The oracle's lux window reaches back while the true light stays within this share of
the tolerance of today's: the rest of the tolerance is the window's own bias."""
HINDSIGHT_LUX_WINDOW_S = 4.0  # ... and at most this far back, seconds
HINDSIGHT_CUT_SIGMAS = 4.5
"""A second difference of the readings' errors beyond this many of its true sigmas is
a spike, and the oracle's lux leaves it out."""
HINDSIGHT_MIN_SAMPLES = 10  # fewer second differences in the window: no figure

METHODS = ("raw", "median5", "lunad", "oracle")
WORLDS = ("paper", "shot")


class Sensor(Protocol):
    """What a world must do: draw one reading for a truth, and say its amp."""

    def sample(self, truth: Truth, rng: random.Random, amp_threshold: int = ...) -> RawReading:
        """One reading for ``truth``."""
        ...

    def amp_of(self, truth: Truth) -> float:
        """The amp ``truth`` returns before jitter and the sensor's limits."""
        ...


def make_sensor(world: str, noise_scale: float = 1.0) -> Sensor:
    """The sensor physics of ``world`` (one of WORLDS)."""
    if world == "paper":
        return RealisticSensor(noise_scale)
    if world == "shot":
        return ShotNoiseSensor(noise_scale)
    raise ValueError(f"unknown world {world!r}; one of {', '.join(WORLDS)}")


@dataclass(frozen=True, slots=True)
class MethodResult:
    """One method's metrics on one run (None where a metric does not apply).

    Attributes: as the module docstring's metrics; ``rmse_m`` in metres.
    """

    method: str
    rmse_m: float | None
    coverage: float
    two_sigma: float | None
    five_sigma: float | None
    bad_frames: int
    step_lag_frames: int | None
    lux_ok: float | None
    lux_null: float | None


@dataclass(frozen=True, slots=True)
class ScenarioResult:
    """All methods on one scenario, world and seed.

    Attributes:
        scenario: scenario name.
        world: the sensor physics (one of WORLDS).
        seed: the noise draw.
        n_frames: frames evaluated.
        rate_hz: frame rate, Hz.
        n_steps: distance steps in the scenario.
        oracle_q: the oracle's process noise chosen in hindsight, m^2/s^3.
        vs_oracle: lunad's RMSE over the oracle's, on frames both published.
        vs_median5: lunad's RMSE over median5's, on frames both published.
        methods: one result per method, in METHODS order.
        mixed_frames: readings of a beam on two surfaces (edges.py).
        mixed_ok: of those, the ones lunad published ``ok``.
    """

    scenario: str
    world: str
    seed: int
    n_frames: int
    rate_hz: float
    n_steps: int
    oracle_q: float
    vs_oracle: float | None
    vs_median5: float | None
    methods: tuple[MethodResult, ...]
    mixed_frames: int = 0
    mixed_ok: int = 0

    def get(self, method: str) -> MethodResult:
        """The result of ``method``."""
        for m in self.methods:
            if m.method == method:
                return m
        raise KeyError(method)


@dataclass(frozen=True, slots=True)
class EvalReport:
    """Everything ``lunad eval`` prints.

    Attributes:
        noise_scale: the worlds' noise factor.
        scenarios: one result per scenario, world and seed.
        step_cost_us: mean cost of one RangeFilter.step, microseconds.
        true_noise: whether lunad was told each reading's true sigma (a diagnostic).
        filter_settings: lunad's FilterConfig fields that differ from the defaults
            (empty: the daemon's defaults were judged).
    """

    noise_scale: float
    scenarios: tuple[ScenarioResult, ...]
    step_cost_us: float
    true_noise: bool = False
    filter_settings: tuple[tuple[str, float | int], ...] = ()

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class Run:
    """The inputs and truths of one scenario run.

    Attributes:
        truth: the truth per frame.
        raw_m: reported distance per frame, metres (None when none).
        amp: reported amp per frame.
        t_ns: frame times, nanoseconds.
        sigma_m: the true one-sigma noise per frame, metres (None without a distance).
        mixed: per frame, whether the reading mixes two surfaces at an edge (edges.py);
            empty for a run made without them.
    """

    truth: tuple[Truth, ...]
    raw_m: tuple[float | None, ...]
    amp: tuple[int, ...]
    t_ns: tuple[int, ...]
    sigma_m: tuple[float | None, ...]
    mixed: tuple[bool, ...] = ()


def simulate(
    scenario: Scenario, world: str = "paper", noise_scale: float = 1.0, seed: int = 0
) -> Run:
    """Draw one seeded run of ``scenario`` from ``world``'s sensor; the readings right
    after each distance step see both surfaces (edges.py)."""
    sensor = make_sensor(world, noise_scale)
    rng = random.Random(f"{seed}:{scenario.name}")
    view = edge_view(scenario.step_times_s, scenario.truth_at, sensor.amp_of)
    truth: list[Truth] = []
    raw_m: list[float | None] = []
    amps: list[int] = []
    t_ns: list[int] = []
    sigmas: list[float | None] = []
    mixed: list[bool] = []
    for t in scenario.frame_times():
        tr = scenario.truth_at(t)
        seen = view(t, tr)
        rd = sensor.sample(seen, rng)
        truth.append(tr)
        raw_m.append(rd.dist_cm * 0.01 if rd.dist_cm else None)
        amps.append(rd.amp)
        t_ns.append(round(t * 1e9))
        sigmas.append(rd.sigma_m)
        mixed.append(seen is not tr and rd.dist_cm > 0)
    return Run(tuple(truth), tuple(raw_m), tuple(amps), tuple(t_ns), tuple(sigmas), tuple(mixed))


def _median5(run: Run) -> list[float | None]:
    window: list[float] = []
    out: list[float | None] = []
    for z, amp in zip(run.raw_m, run.amp, strict=True):
        if z is None or not AMP_WEAK <= amp <= AMP_AMBIENT:
            out.append(None)
            continue
        window.append(z)
        if len(window) > MEDIAN_WINDOW:
            del window[0]
        ordered = sorted(window)
        n = len(ordered)
        mid = n // 2
        out.append(ordered[mid] if n % 2 else 0.5 * (ordered[mid - 1] + ordered[mid]))
    return out


def _lunad(
    run: Run, config: FilterConfig | None, true_noise: bool = False
) -> tuple[list[float | None], list[float | None], list[float | None], list[bool]]:
    """lunad's estimates, sigmas, lux figures (None where no range is published) and
    whether each frame was published ``ok``. With ``true_noise``, the filter is told
    each reading's true sigma before it takes the reading (a diagnostic: its tracker
    with the oracle's knowledge of the noise)."""
    flt = RangeFilter(config)
    est: list[float | None] = []
    sig: list[float | None] = []
    lux: list[float | None] = []
    ok: list[bool] = []
    for z, amp, t, sigma in zip(run.raw_m, run.amp, run.t_ns, run.sigma_m, strict=True):
        if true_noise and sigma is not None and amp > 0:
            flt.assume_reading_sigma(sigma, amp)
        e = flt.step(z, amp, t)
        est.append(e.range_m)
        sig.append(e.sigma_m)
        lux.append(e.lux_est if e.range_m is not None else None)
        ok.append(e.status is Status.OK)
    return est, sig, lux, ok


def _away(n: int, step_frames: Sequence[int], settle: int) -> list[bool]:
    away = [True] * n
    for f in step_frames:
        for i in range(f, min(n, f + settle)):
            away[i] = False
    return away


def _lux_settled(run: Run, rate_hz: float) -> list[bool]:
    """Frames whose true light stayed within the tolerance for LUX_SETTLE_S before."""
    n = len(run.truth)
    back = max(1, round(LUX_SETTLE_S * rate_hz))
    stride = max(1, back // 5)
    out = []
    for i in range(n):
        now = run.truth[i].lux
        tol = max(LUX_REL_TOL * now, LUX_ABS_TOL_LUX)
        out.append(
            i >= back
            and all(abs(run.truth[j].lux - now) <= tol for j in range(i - back, i, stride))
        )
    return out


def _hindsight_lux(
    run: Run,
    readable: Sequence[bool],
    settled: Sequence[bool],
    rate_hz: float,
    config: FilterConfig,
) -> list[float | None]:
    """The oracle's lux figure per frame (module doc), lux; None where it is not judged:
    not settled, the true noise under the output step, or too few samples. ``readable``:
    frames whose reading the sensor's own rule accepts (evaluate_run)."""
    n = len(run.truth)
    q = config.resolution_m * config.resolution_m / 12.0
    ref2 = config.amp_ref * config.amp_ref
    # Prefix sums of the clean samples of c^2 (m^2) and of their count.
    total = [0.0] * (n + 1)
    count = [0] * (n + 1)
    for i in range(n):
        v = None
        if i >= 2:
            z0, z1, z2 = run.raw_m[i], run.raw_m[i - 1], run.raw_m[i - 2]
            s0, s1, s2 = run.sigma_m[i], run.sigma_m[i - 1], run.sigma_m[i - 2]
            a0, a1, a2 = run.amp[i], run.amp[i - 1], run.amp[i - 2]
            if (
                readable[i]
                and readable[i - 1]
                and readable[i - 2]
                and z0 is not None  # as readable says; for the type checker
                and z1 is not None
                and z2 is not None
                and s0 is not None
                and s1 is not None
                and s2 is not None
                and min(s0, s1, s2) >= config.resolution_m  # Sheppard's q holds
                and not any(run.mixed[i - 2 : i + 1])  # an edge: two surfaces
            ):
                t0, t1, t2 = (run.truth[i - k].distance_m for k in range(3))
                d = (z0 - t0) - 2.0 * (z1 - t1) + (z2 - t2)  # the noise's: motion known
                sd = math.sqrt(s0 * s0 + 4.0 * s1 * s1 + s2 * s2 + 6.0 * q)
                if abs(d) <= HINDSIGHT_CUT_SIGMAS * sd:
                    v = (d * d - 6.0 * q) / (
                        ref2 / (a0 * a0) + 4 * ref2 / (a1 * a1) + ref2 / (a2 * a2)
                    )
        total[i + 1] = total[i] + (v if v is not None else 0.0)
        count[i + 1] = count[i] + (v is not None)
    back_max = max(1, round(HINDSIGHT_LUX_WINDOW_S * rate_hz))
    out: list[float | None] = [None] * n
    last = math.nan
    start: int | None = None  # the window's first frame, while the light stays ``last``
    for i in range(n):
        now = run.truth[i].lux
        if now != last:
            last = now
            start = None
        sig = run.sigma_m[i]
        if not settled[i] or sig is None or sig < config.resolution_m:
            continue
        stop = max(0, i - back_max)
        if start is None:
            band = HINDSIGHT_LUX_BAND * max(LUX_REL_TOL * now, LUX_ABS_TOL_LUX)
            start = i
            while start > stop and abs(run.truth[start - 1].lux - now) <= band:
                start -= 1
        j = max(start, stop)
        k = count[i + 1] - count[j]
        if k < HINDSIGHT_MIN_SAMPLES:
            continue
        c = math.sqrt(max(0.0, (total[i + 1] - total[j]) / k))
        out[i] = max(0.0, (c - config.sigma0_m) / config.k_m_per_lux)
    return out


def _shared_rmse(
    a: Sequence[float | None],
    b: Sequence[float | None],
    truth: Sequence[float],
    away: Sequence[bool],
) -> float | None:
    """RMSE of ``a`` over RMSE of ``b``, on away frames where both published."""
    sa = sb = 0.0
    n = 0
    for ea, eb, tr, ok in zip(a, b, truth, away, strict=True):
        if ok and ea is not None and eb is not None:
            sa += (ea - tr) ** 2
            sb += (eb - tr) ** 2
            n += 1
    if not n or sb == 0.0:
        return None
    return math.sqrt(sa / sb)


def _metrics(
    name: str,
    readable: Sequence[bool],
    est: Sequence[float | None],
    sig: Sequence[float | None] | None,
    truth: Sequence[float],
    step_frames: Sequence[int],
    away: Sequence[bool],
    lux: Sequence[float | None] | None = None,
    true_lux: Sequence[float] | None = None,
    lux_settled: Sequence[bool] | None = None,
) -> MethodResult:
    n = len(truth)
    grace = [False] * n
    for f in step_frames:
        for i in range(f, min(n, f + STEP_GRACE_FRAMES)):
            grace[i] = True
    published = n_away = bad = inside = beyond = with_sigma = 0
    sq = 0.0
    for i in range(n):
        e = est[i]
        if e is None:
            continue
        published += 1
        err = abs(e - truth[i])
        if not grace[i] and err > BAD_ERROR_M:
            bad += 1
        if away[i]:
            n_away += 1
            sq += err * err
        s = sig[i] if sig is not None else None
        if s is not None:
            with_sigma += 1
            inside += err <= 2.0 * s
            beyond += err > 5.0 * s
    lag: int | None = None
    for f in step_frames:
        k = 0  # frames with a reading the sensor vouches for, until the step is followed
        i = f
        while i < n:
            e = est[i]
            if e is not None and abs(e - truth[i]) <= LAG_ERROR_M:
                break
            k += readable[i]
            i += 1
        lag = k if lag is None else max(lag, k)
    lux_ok = lux_null = None
    if lux is not None and true_lux is not None and lux_settled is not None:
        judged = good = nulls = 0
        for i in range(n):
            if est[i] is None:
                continue
            li = lux[i]
            if li is None:
                nulls += 1
            elif lux_settled[i]:
                judged += 1
                tl = true_lux[i]
                good += abs(li - tl) <= max(LUX_REL_TOL * tl, LUX_ABS_TOL_LUX)
        lux_ok = good / judged if judged else None
        lux_null = nulls / published if published else None
    return MethodResult(
        method=name,
        rmse_m=math.sqrt(sq / n_away) if n_away else None,
        coverage=published / n if n else 0.0,
        two_sigma=inside / with_sigma if with_sigma else None,
        five_sigma=beyond / with_sigma if with_sigma else None,
        bad_frames=bad,
        step_lag_frames=lag,
        lux_ok=lux_ok,
        lux_null=lux_null,
    )


def evaluate_run(
    scenario: Scenario,
    run: Run,
    world: str = "paper",
    seed: int = 0,
    config: FilterConfig | None = None,
    true_noise: bool = False,
) -> ScenarioResult:
    """Feed one run to every method and score them against the truth. With
    ``true_noise``, lunad's filter is told each reading's true sigma (``_lunad``)."""
    config = config or FilterConfig()
    truth = [tr.distance_m for tr in run.truth]
    n = len(truth)
    steps = scenario.step_frames()
    settle = max(STEP_GRACE_FRAMES, round(STEP_SETTLE_S * scenario.rate_hz))
    away = _away(n, steps, settle)

    def oracle_score(est: list[float | None], sig: list[float | None]) -> float:
        sq = 0.0
        k = 0
        for e, tr, ok in zip(est, truth, away, strict=True):
            if ok and e is not None:
                sq += (e - tr) ** 2
                k += 1
        return math.sqrt(sq / k) if k else math.inf

    q, o_est, o_sig = tuned_oracle(
        run.raw_m, run.amp, run.t_ns, run.sigma_m, oracle_score, max_coast_s=ORACLE_MAX_COAST_S
    )
    m_est = _median5(run)
    l_est, l_sig, l_lux, l_ok = _lunad(run, config, true_noise)
    true_lux = [tr.lux for tr in run.truth]
    settled = _lux_settled(run, scenario.rate_hz)
    readable = [
        z is not None and AMP_WEAK <= a <= AMP_AMBIENT
        for z, a in zip(run.raw_m, run.amp, strict=True)
    ]
    results = (
        _metrics("raw", readable, run.raw_m, None, truth, steps, away),
        _metrics("median5", readable, m_est, None, truth, steps, away),
        _metrics("lunad", readable, l_est, l_sig, truth, steps, away, l_lux, true_lux, settled),
        _metrics(
            "oracle",
            readable,
            o_est,
            o_sig,
            truth,
            steps,
            away,
            _hindsight_lux(run, readable, settled, scenario.rate_hz, config),
            true_lux,
            settled,
        ),
    )
    return ScenarioResult(
        scenario=scenario.name,
        world=world,
        seed=seed,
        n_frames=n,
        rate_hz=scenario.rate_hz,
        n_steps=len(steps),
        oracle_q=q,
        vs_oracle=_shared_rmse(l_est, o_est, truth, away),
        vs_median5=_shared_rmse(l_est, m_est, truth, away),
        methods=results,
        mixed_frames=sum(run.mixed),
        mixed_ok=sum(m and k for m, k in zip(run.mixed, l_ok, strict=False)),
    )


def evaluate(
    scenario: Scenario,
    world: str = "paper",
    noise_scale: float = 1.0,
    seed: int = 0,
    config: FilterConfig | None = None,
) -> ScenarioResult:
    """Simulate ``scenario`` in ``world`` and score every method."""
    run = simulate(scenario, world, noise_scale, seed)
    return evaluate_run(scenario, run, world, seed, config)


def step_cost_us(run: Run, config: FilterConfig | None = None, repeat: int = 3) -> float:
    """Mean wall time of one RangeFilter.step over ``run``'s frames, microseconds.

    The best of ``repeat`` passes (least disturbed by the machine). A report, not a test.
    """
    best = math.inf
    frames = list(zip(run.raw_m, run.amp, run.t_ns, strict=True))
    for _ in range(repeat):
        flt = RangeFilter(config)
        step = flt.step
        t0 = time.perf_counter_ns()
        for raw_m, amp, t_ns in frames:
            step(raw_m, amp, t_ns)
        best = min(best, (time.perf_counter_ns() - t0) / max(1, len(frames)))
    return best / 1000.0


def _evaluate_one(
    job: tuple[Scenario, str, int, float, FilterConfig | None, bool],
) -> ScenarioResult:
    """One run of ``evaluate_all``: simulate, then score every method. At module level so
    that a worker process can be handed it."""
    scenario, world, seed, noise_scale, config, true_noise = job
    run = simulate(scenario, world, noise_scale, seed)
    return evaluate_run(scenario, run, world, seed, config, true_noise)


def _changed_settings(config: FilterConfig | None) -> tuple[tuple[str, float | int], ...]:
    """The fields of ``config`` that differ from ``FilterConfig()``, in field order."""
    if config is None:
        return ()
    default = FilterConfig()
    return tuple(
        (f.name, getattr(config, f.name))
        for f in fields(FilterConfig)
        if getattr(config, f.name) != getattr(default, f.name)
    )


def evaluate_all(
    scenarios: Iterable[Scenario],
    worlds: Sequence[str] = WORLDS,
    seeds: Sequence[int] = (0,),
    noise_scale: float = 1.0,
    config: FilterConfig | None = None,
    true_noise: bool = False,
    jobs: int = 1,
) -> EvalReport:
    """Evaluate every scenario in every world at every seed; time RangeFilter.step on
    the longest run. With ``true_noise``, lunad is told each reading's true sigma.

    ``jobs`` worker processes share the runs (each run is drawn from its own seed, so
    the results are the same whatever their number, in the same order); the step's
    cost is timed in this process, alone."""
    runs = [
        (sc, world, seed, noise_scale, config, true_noise)
        for sc in scenarios
        for world in worlds
        for seed in seeds
    ]
    if jobs > 1 and len(runs) > 1:
        workers = min(jobs, len(runs))
        with ProcessPoolExecutor(max_workers=workers) as pool:
            chunk = max(1, len(runs) // (4 * workers))
            results = list(pool.map(_evaluate_one, runs, chunksize=chunk))
    else:
        results = [_evaluate_one(job) for job in runs]
    cost = 0.0
    if results:
        longest = max(range(len(results)), key=lambda i: (results[i].n_frames, -i))
        sc, world, seed = runs[longest][:3]
        cost = step_cost_us(simulate(sc, world, noise_scale, seed), config)
    return EvalReport(noise_scale, tuple(results), cost, true_noise, _changed_settings(config))


@dataclass(frozen=True, slots=True)
class Targets:
    """The targets lunad must meet on every scenario, world and seed.

    Attributes:
        oracle_ratio: RMSE away from steps at most this times the oracle's.
        two_sigma_lo, two_sigma_hi: 2-sigma coverage inside this band.
        five_sigma: share of estimates more than 5 sigma off below this.
        step_lag_frames: at most this many frames.
        lux_ok: share of settled lux figures within tolerance at least this.
    """

    oracle_ratio: float = 1.3
    two_sigma_lo: float = 0.90
    two_sigma_hi: float = 0.99
    five_sigma: float = 0.005
    step_lag_frames: int = 3
    lux_ok: float = 0.95


MISS_KINDS = {
    "nothing": "nothing published",
    "rmse_oracle": "RMSE against the oracle",
    "rmse_median5": "RMSE against median5",
    "two_sigma": "2-sigma coverage",
    "five_sigma": "beyond 5 sigma",
    "bad_outputs": "bad outputs",
    "step_lag": "step lag",
    "edge_ok": "edge readings published ok",
    "lux": "lux",
}
"""The kinds of target a run can miss, and how the summary names them."""


@dataclass(frozen=True, slots=True)
class Miss:
    """One target lunad missed on one run.

    Attributes:
        kind: one of ``MISS_KINDS``.
        text: the sentence ``lunad eval`` prints.
        oracle_too: the oracle misses it too: its own 2-sigma coverage strays from
            the band as lunad's does, or its lux, read in hindsight, says that the
            readings of this run do not hold the light to the target's precision.
    """

    kind: str
    text: str
    oracle_too: bool = False


def target_misses(result: ScenarioResult, targets: Targets | None = None) -> list[Miss]:
    """Targets lunad misses on one run (empty: all met)."""
    tg = targets or Targets()
    mine = result.get("lunad")
    name = f"{result.scenario}/{result.world}/seed {result.seed}"
    misses: list[Miss] = []

    def miss(kind: str, text: str, oracle_too: bool = False) -> None:
        misses.append(Miss(kind, f"{name}: {text}", oracle_too))

    if mine.rmse_m is None:
        miss("nothing", "lunad published nothing away from steps")
        return misses
    if result.vs_oracle is not None and result.vs_oracle > tg.oracle_ratio:
        miss("rmse_oracle", f"RMSE {result.vs_oracle:.2f} x the oracle's > {tg.oracle_ratio}")
    if result.vs_median5 is not None and result.vs_median5 >= 1.0:
        miss("rmse_median5", f"RMSE {result.vs_median5:.2f} x median5's, not below it")
    if mine.two_sigma is not None and not tg.two_sigma_lo <= mine.two_sigma <= tg.two_sigma_hi:
        theirs = result.get("oracle").two_sigma
        too = theirs is not None and not tg.two_sigma_lo <= theirs <= tg.two_sigma_hi
        why = f" (the oracle's own: {theirs:.1%})" if too and theirs is not None else ""
        miss(
            "two_sigma",
            f"2-sigma coverage {mine.two_sigma:.1%} outside "
            f"[{tg.two_sigma_lo:.0%}, {tg.two_sigma_hi:.0%}]{why}",
            too,
        )
    if mine.five_sigma is not None and mine.five_sigma >= tg.five_sigma:
        miss(
            "five_sigma",
            f"{mine.five_sigma:.2%} of estimates beyond 5 sigma >= {tg.five_sigma:.1%}",
        )
    if mine.bad_frames:
        miss(
            "bad_outputs",
            f"{mine.bad_frames} usable outputs more than {BAD_ERROR_M:g} m off "
            f"beyond {STEP_GRACE_FRAMES} frames after a step",
        )
    if mine.step_lag_frames is not None and mine.step_lag_frames > tg.step_lag_frames:
        miss("step_lag", f"step lag {mine.step_lag_frames} frames > {tg.step_lag_frames}")
    if result.mixed_ok:
        miss(
            "edge_ok",
            f"{result.mixed_ok} of {result.mixed_frames} readings of two surfaces "
            "at an edge published ok",
        )
    if mine.lux_ok is not None and mine.lux_ok < tg.lux_ok:
        hind = result.get("oracle").lux_ok
        too = hind is not None and hind < tg.lux_ok
        why = f" (the oracle's, read in hindsight: {hind:.1%})" if too and hind is not None else ""
        miss(
            "lux",
            f"lux within {LUX_REL_TOL:.0%} or {LUX_ABS_TOL_LUX / 1000:g} klux on "
            f"{mine.lux_ok:.1%} of settled frames < {tg.lux_ok:.0%}{why}",
            too,
        )
    return misses


def check_targets(result: ScenarioResult, targets: Targets | None = None) -> list[str]:
    """Targets lunad misses on one run, as sentences (empty: all met)."""
    return [m.text for m in target_misses(result, targets)]


def _fmt(v: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "-" if v is None else f"{v * scale:.{digits}f}"


def _conditions(report: EvalReport) -> str:
    """The noise factor, whether lunad was told the noise, and its filter settings."""
    told = (
        "; lunad told each reading's true sigma, as the oracle is (a diagnostic)"
        if report.true_noise
        else ""
    )
    settings = ", ".join(f"{k}={v:g}" for k, v in report.filter_settings) or "defaults"
    return f"noise x{report.noise_scale:g}{told}; lunad's filter: {settings}"


def format_summary(report: EvalReport, targets: Targets | None = None) -> str:
    """The tally ``lunad eval --summary`` prints: the targets missed by kind, then a
    table of them by scenario and world, split by kind, without a line per run (a
    comparison of two filters wants hundreds of seeds: docs/filter.md, "Seeds beyond
    the three")."""
    results = report.scenarios
    seeds = {r.seed for r in results}
    names = list(dict.fromkeys(r.scenario for r in results))
    worlds = list(dict.fromkeys(r.world for r in results))
    per_run = [target_misses(r, targets) for r in results]
    every = [m for ms in per_run for m in ms]
    lines = [
        f"lunad eval: {len(results)} runs ({len(names)} scenarios x {len(worlds)} worlds x "
        f"{len(seeds)} seeds), {_conditions(report)}",
        f"RangeFilter.step: {report.step_cost_us:.2f} us per frame (this machine)",
    ]
    if not results:
        return "\n".join(lines)
    kinds = Counter(m.kind for m in every)
    too = Counter(m.kind for m in every if m.oracle_too)
    lines.append(
        f"targets missed: {len(every)}, {24 * len(every) / len(results):.1f} per 24 runs"
        f" ({sum(too.values())} of them where the oracle misses too)"
    )
    for kind, label in MISS_KINDS.items():
        if kinds[kind]:
            also = f" ({too[kind]} where the oracle misses too)" if too[kind] else ""
            lines.append(f"  {label:<27} {kinds[kind]:>6}{also}")
    shown = [kind for kind in MISS_KINDS if kinds[kind]]
    lines.append(
        "targets missed by scenario and world (oracle_too: of them, where the oracle"
        " misses too), and by kind:"
    )
    cells: Counter[tuple[str, str, str]] = Counter()
    runs: Counter[tuple[str, str]] = Counter()
    for r, ms in zip(results, per_run, strict=True):
        runs[r.scenario, r.world] += 1
        for m in ms:
            cells[r.scenario, r.world, m.kind] += 1
            cells[r.scenario, r.world, "missed"] += 1
            cells[r.scenario, r.world, "oracle_too"] += m.oracle_too
    width = max(len(n) for n in (*names, "scenario"))
    columns = ["missed", "oracle_too", *shown]
    lines.append(
        f"  {'scenario':<{width}} {'world':<5} {'runs':>5} "
        + " ".join(f"{c:>{max(len(c), 4)}}" for c in columns)
    )
    for name in names:
        for w in worlds:
            row = (f"{cells[name, w, c]:>{max(len(c), 4)}}" for c in columns)
            lines.append(f"  {name:<{width}} {w:<5} {runs[name, w]:>5} " + " ".join(row))
    return "\n".join(lines)


def format_table(report: EvalReport, targets: Targets | None = None) -> str:
    """The human-readable report ``lunad eval`` prints: one line per run and method."""
    lines = [f"lunad eval: worlds paper and shot (sim/evaluate.py), {_conditions(report)}", ""]
    head = (
        f"{'method':<8} {'rmse_cm':>8} {'cover_%':>8} {'2sig_%':>7} {'5sig_%':>7} "
        f"{'bad':>4} {'lag_fr':>6} {'lux_ok%':>7} {'luxnull%':>8}"
    )
    all_misses: list[str] = []
    for res in report.scenarios:
        lines.append(
            f"== {res.scenario} / {res.world} / seed {res.seed}: {res.n_frames} frames at "
            f"{res.rate_hz:g} Hz, {res.n_steps} steps; lunad / oracle {_fmt(res.vs_oracle)}"
            f" (oracle q {res.oracle_q:.2g} m^2/s^3), lunad / median5 {_fmt(res.vs_median5)};"
            f" {res.mixed_frames} edge readings, {res.mixed_ok} published ok"
        )
        lines.append(head)
        for m in res.methods:
            lag = "-" if m.step_lag_frames is None else str(m.step_lag_frames)
            lines.append(
                f"{m.method:<8} {_fmt(m.rmse_m, 100):>8} {_fmt(m.coverage, 100, 1):>8} "
                f"{_fmt(m.two_sigma, 100, 1):>7} {_fmt(m.five_sigma, 100, 2):>7} "
                f"{m.bad_frames:>4} {lag:>6} {_fmt(m.lux_ok, 100, 1):>7} "
                f"{_fmt(m.lux_null, 100, 1):>8}"
            )
        lines.append("")
        all_misses.extend(check_targets(res, targets))
    lines.append(f"RangeFilter.step: {report.step_cost_us:.2f} us per frame (this machine)")
    if all_misses:
        lines.append(f"targets missed ({len(all_misses)}):")
        lines.extend(f"  {m}" for m in all_misses)
    else:
        lines.append("targets: all met")
    return "\n".join(lines)

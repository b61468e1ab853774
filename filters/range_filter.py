"""The per-frame cleaning pipeline the daemon runs: gates, noise, tracker, sigma, zone.

How this works, per frame (docs/architecture.md, "One reading"; docs/filter.md has the
evidence for each choice):

1. S = amp / amp_ref (paper eq. 1, amp_ref from ``lunad calibrate``).
2. Hard gates with hysteresis (policy.py) -> ``dropout``. A reading inside a
   hysteresis band, or a little beyond the range, still feeds the filter; one in the
   weak gate's band (above amp_min, not yet back above the band) is published
   ``degraded`` with ``weak_signal``, so a track is not hidden while the amp climbs.
3. The noise: c = sigma0 + k L (paper eq. 2) measured from the second differences of
   the raw readings (noise.py), which smooth motion and steps do not move. The
   reading's variance is r = c^2 / S^2 + q (paper eq. 3, q the 1 cm steps) with c
   from the fast average, which follows a change of light within about 0.3 s;
   L_hat = (c - sigma0) / k from the slow average (its lag on a ramp of light added
   back), fed only while the noise is above the output step and near its floor
   (minimum statistics: clutter is not light; a wider bound while a still track's
   light is seen rising, since the floor lags the ramp), is published there and null
   elsewhere, and null until it has been measured (``LIGHT_MEASURED_SPANS`` spans of
   observable readings after a start). After a start the fast average starts again
   from the median of the first ``NOISE_BOOT_SAMPLES`` second differences, and the
   first track, which weighted its readings by the prior's variance, runs again over
   them with the measured one, as a nearly still target's (``_refilter``,
   ``BOOT_SPEED_SIGMA_M_S``).
4. A constant-velocity Kalman filter whose process noise adapts to manoeuvres: it
   runs at ``accel_psd`` (nearly still: it averages a still target like a mean)
   until the innovations carry a bias that their own spread cannot explain, then at
   ``manoeuvre_accel_psd`` for ``manoeuvre_frames`` more readings (and for as many
   after a track starts, its speed unknown). The test is self-normalised: a running
   mean m of the innovations over N readings fires when
   m^2 > T^2 (1 - rho) / (1 + rho) times their mean square (rho = 1 - 1/N), once
   with N = ``manoeuvre_frames`` (a sudden manoeuvre) and once with five times as
   many (a small lag that a noisy reading hides, at T = ``DRIFT_SIGMAS``). On a
   still track the fast test waits while the noise of the readings rises (the
   light's fast noise average above the floor's ``MIN_STATS_NEAR``, noise.py): under
   a jump of light ten noisy readings pass its threshold against a mean square that
   still lags the jump, and a bias does not move the second differences the noise is
   read from (docs/filter.md section 4). When it fires after a quiet stretch, P00
   gains the fast mean's squared bias (m^2 less its scatter's share):
   ``manoeuvre_accel_psd`` alone adds qa dt a frame to the speed's
   variance, which reaches P00 only over several frames, so the hold's first frames
   would still trust the lagging track. A while after a hold the track as it was
   goes on beside the hold as the still track, and is taken back when the next
   ``SHADOW_FRAMES`` readings favour it: a test fired by noise does not leave the
   track chasing it. An innovation beyond ``gate_sigmas`` is an ``outlier``;
   ``step_confirm`` outliers that agree with each other restart the track at them (a
   step), published ``degraded`` when their amps part (``EDGE_AMP_RATIO``: an edge's
   mixed readings); so do ``EDGE_RUN`` outliers each further off than the last and
   ``SIDE_RUN`` on one side, at the latest of them (an edge crossed).
5. The published sigma is honest about what P cannot see: the track's variance plus,
   for each running mean, the part of m^2 that its own scatter (1 - rho) / (1 + rho)
   times the mean square does not explain: a bias of the track (a lag, a start of
   motion). The track's variance is P00 while a manoeuvre lasts and 3/4 of it once
   the filter has settled after one (``STILL_VAR_RATIO``): P counts an acceleration
   that a target that stopped, or moves at a constant speed, does not have. On an
   outlier frame the sigma covers the disagreement with the reading, unless that
   sigma would pass ``sigma_unreliable_m``: then the frame is a ``dropout``; so it
   does on an accepted frame whose reading the track does not explain yet
   (``COVER_SIGMAS``), such as the first readings of a reversal.
   ``stale`` when nothing was accepted for ``stale_after_s``, and on the reading that
   starts the track again after that: one reading alone (a beam back from a surface
   too weak to read, whose first reading mixes two surfaces) is not published until
   the next one agrees with it. ``stale`` too after a start until the boot has
   measured the noise and the first track's own sigma is under
   ``sigma_unreliable_m`` (for at most ``stale_after_s`` from the first track): the
   sigma would be the prior's guess, and a run's first track published from its
   first reading came out 0.3-0.4 m off with a sigma of 5-9 cm where the noise was
   three times the prior's (runs with such bad outputs on ``lunad eval`` seeds 0-2,
   3-8 and 20-29: 0, 2 and 7 against 2, 8 and 13; docs/filter.md section 3).
6. Zone (zone.py) from L_hat (0 where unobservable), S and the published sigma.

One implementation, flat: every frame pays for this at 250 Hz on a Pi Zero 2, and a
call per piece would cost about an eighth more; ``lunad bench`` prints the cost.
"""

from __future__ import annotations

from math import log, sqrt

from lunad.filters.config import AMP_AMBIENT, AMP_SATURATED, FilterConfig
from lunad.filters.estimate import Estimate, Reason, Status, Zone
from lunad.filters.noise import (
    FAST_PRIOR_READINGS,
    GAP_NORMALISERS,
    LIGHT_CUT_SIGMAS,
    LIGHT_MEASURED_SPANS,
    LIGHT_WAIT_SPANS,
    MAX_GAP_FRAMES,
    MIN_STATS_BIAS,
    MIN_STATS_NEAR,
    MIN_STATS_SPANS,
    NOISE_BOOT_SAMPLES,
    NORMAL_MEDIAN_ABS,
    RISING_LEARN_NEAR,
    SLOW_EVERY,
    SLOW_RESTART_SPANS,
    SLOW_RISE_RATIO,
    SLOW_RISE_START,
    SLOW_TREND_GATE,
    d2_scale,
    truncated_abs_mean,
    winsorised_abs_mean,
)
from lunad.filters.policy import band_edge, first_amp_at_least
from lunad.filters.zone import ZoneLimits

RUN_GAP_MAX = 6
"""Frames that do not feed the filter (no distance, a weak or saturated signal) that may
sit between two outliers of one run: a marginal target, weak every other frame, still
confirms its step; two spikes 0.3 s apart, dropouts between them, stay two spikes. A
beam swept past a far, dark corner reads nothing for a while and then, leaving it,
gives readings in the weak band a few frames apart (room_sweep in the shot world: 33
frames without a distance, then readings 5 frames apart): with 2 they never formed a
run, and the step was followed on the fourth reading. ``lunad eval``, seeds 140-159
(the choice) and 160-179: step lags over 3 frames 9 and 5 with 2, 3 and 4 with 4, 2
and 4 with 6 (10 as 6), and no other target moved there; on seeds 0-179, 1680
targets missed against 1710, and three targets other than step lags moved
(docs/filter.md, "How it is judged")."""

EDGE_RUN = 3
"""Outliers in a row on one side of the track, each further from it than the one
before, that restart the track at the latest of them: the beam crossing an edge, whose
first readings mix the two surfaces (sim/edges.py) and so agree with neither each
other nor the track, which ``step_confirm`` needs. The restart's frame is published
``degraded`` (``outlier``) with the reading's own sigma until a reading confirms it.
``lunad eval``, three seeds: every step followed within 2 frames instead of 3."""

SIDE_RUN = 4
"""Outliers in a row on one side of the track, however they lie among themselves, that
restart it at the latest of them, published ``degraded`` (``outlier``) as an
``EDGE_RUN`` restart is: the track is gone. At an edge the mixed readings can jump
about (alternating in the paper world, seed 14: 2.90, 1.75 and 2.87 m between a wall
at 5 m and an object at 1 m), so that neither ``step_confirm`` nor ``EDGE_RUN`` sees
them, and the first clean reading was an outlier too: the step was followed on the
fifth frame. ``lunad eval``, seeds 0-8, 10-29, 30-39, 40-49, 80-89 and 90-99: step
lags over 3 frames 4, 10, 4, 4, 0 and 4 before, 2, 5, 3, 4, 0 and 4 with it, and
nothing else moved; 3 restarts on the third mixed reading and changes nothing, 5
changes nothing either."""

EDGE_AMP_RATIO = 1.3
"""Outliers that agree in distance, ``step_confirm`` of them, restart the track at
their mean; when two in a row differ in amp by more than this factor, the restart's
frame is published ``degraded`` (``outlier``), as an ``EDGE_RUN`` restart is, until a
reading confirms it. At an edge two readings can mix the two surfaces at about the
same distance while the amp moves with the mix: alternating in the paper world, seed
53, read 2.87 and 2.92 m (amps 554 and 400) between walls at 1 and 5 m and published
the second ``ok``. ``lunad eval``, seeds 0-8: of 1288 restarts on agreeing outliers,
11 are flagged, all with an edge reading among them, none on a clean step; no target
changes on seeds 0-8 and 60-69, and that edge reading is no longer ``ok``. The
simulated amp is steadier than a real one: in the real roadside log a quarter of
consecutive readings within 3 cm of each other differ in amp by more than 1.3x, so on
a sensor the first frame after a step will often be ``degraded`` too."""

SAME_AMP_SHARE = 0.12
"""A run of ``step_confirm`` agreeing outliers whose amps all lie within this share of
the track's amp (``TRACK_AMP_GAIN``), on a still track (``STILL_SPEED_M_S``),
restarts the track only on one more agreeing outlier. The amp reports the surface the
beam is on, not the noisy distance: a step to another surface or distance moves it (a
surface 35 cm behind one at 3 m returns about 20 % less, d^2), a noise excursion of
the same surface does not. The simulated amp jitters by 3 % (paper world) and 5 %
(shot world), so two amps of one surface part by more than 12 % on under 1 % and
about 9 % of pairs. Where the light jumps and the measured noise has not caught up
with it (cloud_flicker: 6.6 to 23 cm of noise within a frame, the reading variance at
the old noise for dozens of readings), two of the first readings beyond the gate on
one side restarted the track 0.3-0.4 m off, and it chased the noise. ``lunad eval``,
seeds 1900-2059 (the choice) and 2060-2219: 1267 and 1263 targets missed against 1320
and 1331, bad outputs 20 and 27 against 47 and 57 (cloud_flicker in the shot world 8
and 9 against 33 and 38), step lags over 3 frames 25 and 29 as before; a share of 8 %
missed 1305 on the first (bad outputs 27), 16 % 1265. A sensor whose amp jitters more
(the real roadside log: a quarter of consecutive readings within 3 cm of each other
part by more than 1.3x) waits less often: the rule then changes less (docs/filter.md
section 4)."""

TRACK_AMP_GAIN = 0.25
"""The track's amp, which ``SAME_AMP_SHARE`` compares a run's amps with, is a running
mean of the amps of the readings the track takes, each weighing this much. The amp of
one surface jitters from reading to reading (3 % in the paper world, 5 % in the shot
world, more on a real sensor): in the shot world a reading of the same surface lies
beyond the share of the last reading's amp on about 9 % of pairs, beyond the mean's
on about 2.5 % (the mean scatters by 0.38 of one reading). The mean follows a new
surface within a few readings. ``lunad eval``, seeds 3100-3259 (the choice) and
3260-3419: 1155 and 1195 targets missed against 1166 and 1202 with the last reading's
amp (bad outputs 8 and 18 against 12 and 20); a weight of 1/8 missed 1157 on the
first, the mean with a share of 10 % 1158; started again from the reading that
restarts the track, the mean lagged a sweep's corners (docs/filter.md section 4)."""

STILL_SPEED_M_S = 0.5
"""The track speed, m/s, below which ``SAME_AMP_SHARE`` applies. A beam sweeping a room
turns at a corner onto a wall of the same material at about the same distance: the
readings past the corner agree with each other and not with the track, at an amp the
track's last reading had. Waiting for a third there lagged the corners: ``lunad
eval``, seeds 1900-2059, room_sweep in the shot world missed its RMSE target against
the oracle on 47 runs without the speed bound, on 19 with it at 0.5 m/s, as with no
wait at all (at 1.0 m/s: 22, and 1268 targets missed in all against 1267)."""
_STILL_V2 = STILL_SPEED_M_S * STILL_SPEED_M_S

COVER_SIGMAS = 3.0
"""An accepted reading further than this many predicted sigmas (sqrt(P00 + r)) from the
track is one the track does not explain yet: the frame's published variance takes
``COVER_SHARE`` of its squared innovation, so that the sigma covers the disagreement
with the sensor. A normal reading lies that far out 0.27 % of the time; the first
readings of a reversal, a corner or a stop nearly always do, before the manoeuvre
test's running means can see them. room_sweep in the shot world, seed 1, at a corner
0.1 s in (3.3 m/s reversing): three frames 2.8-6.1 cm off the truth with a sigma of
0.4-1.2 cm, 7-15 sigmas. ``lunad eval``, seeds 0-8, 10-29 and 80-89: runs with more
than 0.5 % beyond 5 sigma 5, 2 and 3 without the cover, 0, 0 and 1 with it (2σ coverage
outside 90-99 % in 1, 2 and 1 more runs); 2.5 sigmas, 3.5 sigmas and a share of 0.1 or
0.5 did no better (docs/filter.md section 5)."""
COVER_SHARE = 0.25
"""The share of a squared innovation that the published variance takes where it covers
a reading the track does not explain (beyond ``COVER_SIGMAS``, or an ``outlier``): a
quarter puts the reading at two published sigmas from the estimate."""
_COVER2 = COVER_SIGMAS * COVER_SIGMAS

BOOT_TRACK_READINGS = 64
"""The most readings of the first track kept for ``RangeFilter._refilter`` to run it
again over at the noise's boot's end: the boot needs ``NOISE_BOOT_SAMPLES`` second
differences, eleven readings in a row at best and about twice that where every other
frame has none. A boot that outlasts this, or ``stale_after_s`` from the first track
(readings too sparse to measure the noise: a beam that finds a surface once a second),
has its covariance scaled instead, and the memory the filter holds stays bounded
whatever the readings."""

BOOT_SPEED_SIGMA_M_S = 1.0
"""One-sigma prior on the first track's speed, m/s, when ``RangeFilter._refilter`` runs
it again at the noise's boot's end; it then runs at ``accel_psd`` from its first
reading, with no hold. The boot's dozen readings cannot tell a speed under heavy
noise: the slope of 11 readings 4 ms apart under 23 cm of noise (cloud_flicker at 60
klux) scatters by 5.6 m/s. With ``init_speed_sigma_m_s`` (3 m/s) and a hold at
``manoeuvre_accel_psd``, the first track of a still grey card took that scatter for
+2.8 m/s and drifted 0.2 m off over the next 30 frames. A target that does move is
found by the manoeuvre test, which starts a hold as for any manoeuvre; under low noise
the boot's readings fix the speed whatever the prior (the slope of 11 readings under
1 cm scatters by 0.24 m/s). A restart later on (a step, a stale stretch) keeps
``init_speed_sigma_m_s`` and the hold: at 1 m/s for every start, room_sweep missed its
RMSE target on 146 of 160 runs against 13 (``lunad eval``, seeds 1900-1979).
``lunad eval`` on cloud_flicker, wall_drive, approach and room_sweep, seeds 1900-1979
(the choice): 335 targets missed against 374 (RMSE against the oracle 72 against
106); 0.5, 1.41, 2 and 3 m/s with no hold missed 361, 344, 353 and 370; the first
track kept as it is with this one beside it as a still track, judged over 10, 15 or
30 readings (``SHADOW_FRAMES``), 351-357. All scenarios, seeds 1900-2059, 2220-2379
and 100-279: 1194, 1229 and 1402 against 1267, 1300 and 1462. A target already moving
at a start (tests/data/scenes, seeds 1900-1959): a robot driving at 1.5 m/s under 30
klux, 78 targets missed against 92; a card carried off at 2 m/s under 60 klux, 136
against 137, and judged on its first 0.35 s only, 117 against 116 (docs/filter.md
section 3)."""
_BOOT_V0VAR = BOOT_SPEED_SIGMA_M_S * BOOT_SPEED_SIGMA_M_S


DRIFT_SPAN = 5
"""The slow innovation mean (``drift``) and the innovations' mean square span this many
times ``manoeuvre_frames`` readings: the slow mean sees a bias too small for the fast
test (a third of a noisy reading's sigma, left behind by a manoeuvre) and widens sigma
by it. ``lunad eval``, 3 instead of 5: seeds 580-619 and 620-659 missed 371 and 357
targets against 383 and 365 (2, 4 and 8 on seeds 580-619: 372, 377 and 389), but run
once on seeds 3-579 (without seed 9) 5063 against 5066, blocks of 20-60 seeds 13
fewer to 9 more: not kept."""

DRIFT_SIGMAS = 3.0
"""The slow mean's own threshold, in standard deviations of itself (the fast mean's is
``manoeuvre_sigmas``, 3.5): a start of motion under heavy noise builds its bias
slowly (a robot accelerating at 3 m/s^2 under 17 cm of noise, wall_drive in the paper
world, was seen 0.55 s after it started), and a false alarm on a still target is
undone by the still track (``SHADOW_FRAMES``). ``lunad eval``, seeds 180-199 (the
choice) and 200-219: 186 and 201 targets missed against 192 and 209 at 3.5 (RMSE
against the oracle 36 and 38 against 41 and 48); 2.5, 2.75, 3.25 and 4 missed 214,
195, 190 and 196 on seeds 180-199; run once after the choice on seeds 0-179, 1659
against 1680, four blocks of them 1-3 more (docs/filter.md, "How it is judged");
seeds 0-2 19 against 19 (wall_drive in the paper world at seed 2 1.32x the oracle
against 1.48x)."""

STILL_VAR_RATIO = 0.75
"""The track's error variance on a target that does not accelerate, as a share of P00
once the filter has settled at ``accel_psd``: 3/4, whatever ``accel_psd``, the reading
variance and the frame period. P is honest for a target whose acceleration is white
noise of ``accel_psd``; a still target, or one at a constant speed, is quieter than
that, and 2 sqrt(P00) covered 96-97 % of a still target's frames. The ratio comes from
the exact error recursion of a constant-velocity Kalman filter run with its own gains
and no process noise (docs/filter.md section 5; tests/test_filters_range_filter.py)."""

SHADOW_FRAMES = 30
"""Accepted readings over which the still track is judged against the track that left
it. When the manoeuvre test fires, or outliers or a stale stretch restart the track,
``SHADOW_QUIET_S`` or more after a hold (a track's start or a manoeuvre), the
track as it was goes on beside the new one at ``accel_psd`` (a target that holds its
course), fed the same accepted readings, and each reading adds to the log-likelihood
ratio of their predictions; after this many the still track is taken back, settled,
when it is at least as likely. A real manoeuvre or step leaves it behind within a few
readings; a false alarm, a test fired by noise on a still target, leaves the raised
process noise chasing that noise (0.5-4 m/s under 15-23 cm of noise, cloud_flicker),
and the still track explains the readings better. ``lunad eval``, seeds 0-8 and 10-29,
20-49 and 100-119 (the choice): 245, 279 and 206 targets missed against 253, 298 and
213 (RMSE against the oracle 66 and 72 against 76 and 88 on the first two); seeds
120-139, run after the choice, 194 against 199 (RMSE 40 against 48, 2σ coverage 45
against 42: a better track under heavy noise shows a published sigma that was already
too wide, docs/filter.md section 5). Measured against the same change taking the
still track back unsettled (246 and 283 on the first two): judged after any manoeuvre,
not only a quiet stretch, and over 50 readings, 248 and 289, at 605.5 bytecodes a
frame against 585.3 (over 75 readings 249); judged at the end of the hold (10
readings), 165 against 166 on seeds 0-8 and 10-19; each reading's term capped at 2-4
sigmas, 249-251; the larger of the two covariances taken with the still track's state,
255 (RMSE 77). When a still track is judged: ``SHADOW_QUIET_S``; when it is let go
early: ``SHADOW_DROP_LLR``. Taking it back early on strong evidence (a likelihood
ratio of 100, Wald's sequential test) missed 546 targets on seeds 280-339 against
545, with no wait after the hold."""

SHADOW_QUIET_S = 0.2
"""A still track is judged only where a manoeuvre or a restart comes at least this long
after the last hold ended (a track's start or a manoeuvre's ``manoeuvre_frames``):
the track as it was has then run at ``accel_psd`` long enough to be a track that holds
its course. Not the published variance's settling (``STILL_SETTLE_TAUS``): that
scales with the reading noise, and under 60 klux at the start it lies seconds after
the hold, so that a jump of light that restarted the track on two noisy readings
that agreed had no still track beside it (cloud_flicker: the new track chased the
noise at up to 11 m/s). ``lunad eval``, seeds 280-299 and 300-339 together: 547
targets missed against 555 when judged only once settled (RMSE 137 against 146); 545
with no wait after the hold, which judged the still track on a quarter of the frames
of room_sweep, a beam in constant motion (596 bytecodes a frame against 590 on
``lunad bench``); 548 at 0.4 s."""

SHADOW_DROP_LLR = 20.0
"""The still track is let go as soon as the log-likelihood ratio of the track over it
passes this (a ratio of about 5e8): a real step or manoeuvre leaves it that far behind
within a reading or two (a step of 30 cm under 2 cm of noise adds over 100 a reading),
and judging it further costs frames for nothing. A jump of light whose noise the
filter still underestimates threefold adds about 15 on its first reading and must not
end the judging. ``lunad eval``, seeds 280-339: the same 547 targets missed as with no
such limit, at 589.9 bytecodes a frame against 592.5 (``lunad bench``)."""

STILL_SETTLE_TAUS = 3.0
"""After a manoeuvre hold (or a track's start) that error falls from P00 to
``STILL_VAR_RATIO`` P00 between about 1.5 and 5 tau, tau = (r dt / accel_psd)^(1/4)
the filter's settling time (r the reading variance, m^2; dt the frame period, s), on
one curve of t / tau for every r, dt and hold length. The published variance steps
down at this many tau, the middle of the fall: its sigma stays within 0.93-1.10 of
the exact one."""

_SATURATED = (Reason.SATURATED,)
_AMBIENT = (Reason.HIGH_AMBIENT,)
_WEAK = (Reason.WEAK_SIGNAL,)
_CLOSE = (Reason.TOO_CLOSE,)
_FAR = (Reason.TOO_FAR,)
_NO_DISTANCE = (Reason.NO_DISTANCE,)
_WEAK_CLOSE = (Reason.WEAK_SIGNAL, Reason.TOO_CLOSE)
_WEAK_FAR = (Reason.WEAK_SIGNAL, Reason.TOO_FAR)
_UNRELIABLE_ZONE = (Reason.UNRELIABLE_ZONE,)
_AMBIENT_UNRELIABLE = (Reason.HIGH_AMBIENT, Reason.UNRELIABLE_ZONE)
_OUTLIER = (Reason.OUTLIER,)
_WEAK_OUTLIER = (Reason.WEAK_SIGNAL, Reason.OUTLIER)
_OUTLIER_AMBIENT = (Reason.OUTLIER, Reason.HIGH_AMBIENT)
_NONE: tuple[Reason, ...] = ()
_STALE = (Reason.STALE,)
_WEAK_STALE = (Reason.WEAK_SIGNAL, Reason.STALE)
_OK = Status.OK
_DEGRADED = Status.DEGRADED
_DROPOUT = Status.DROPOUT
_STABLE = Zone.STABLE
_MARGINAL = Zone.MARGINAL
_UNRELIABLE = Zone.UNRELIABLE
_INF = float("inf")
_NEVER = 1 << 62
"""A time, nanoseconds, that no clock reaches: an int, for a cheap compare with one."""
_INV_MIN_STATS_BIAS = 1.0 / MIN_STATS_BIAS
_INV_NORMAL_MEDIAN_ABS = 1.0 / NORMAL_MEDIAN_ABS
_UNCONFIRMED = 1e-12
"""The outlier innovation, metres, of a frame that restarted the track on one reading
(``EDGE_RUN``): published as an outlier is, ``degraded``, with no cover to add."""
_new = tuple.__new__
"""Builds an ``Estimate`` from a tuple without the ``NamedTuple``'s generated Python
``__new__``: one C call instead of a Python frame, on every frame."""
_SHADOW_QUIET_NS = round(SHADOW_QUIET_S * 1e9)  # SHADOW_QUIET_S in the clock's unit


def _cv_predicted(
    x: float, v: float, p00: float, p01: float, p11: float, qa: float, dt: float
) -> tuple[float, float, float, float]:
    """The constant-velocity prediction ``dt`` (> 0) seconds ahead of the position ``x``
    (metres) at speed ``v`` (m/s) with covariance ``p00``, ``p01``, ``p11`` under white
    acceleration of spectral density ``qa`` (m^2/s^3): the new x, p00, p01, p11. The
    accepted reading's step inlines the same lines (every frame pays for a call)."""
    qd = qa * dt
    qdt = qd * dt
    dp = dt * p11
    return (
        x + v * dt,
        p00 + dt * (2.0 * p01 + dp + qdt * (1.0 / 3.0)),
        p01 + dp + 0.5 * qdt,
        p11 + qd,
    )


def _cv_updated(
    x: float, v: float, p00: float, p01: float, p11: float, e: float, sp: float, r: float
) -> tuple[float, float, float, float, float]:
    """The constant-velocity track ``x``, ``v`` (metres, m/s) with predicted covariance
    ``p00``, ``p01``, ``p11`` updated by a reading ``e`` (metres) off its prediction, of
    variance ``r`` (m^2), ``sp`` = p00 + r: the new x, v, p00, p01, p11 (p00 r / sp for
    p00 - k0 p00, and so on). The accepted reading's step inlines the same lines."""
    k0 = p00 / sp
    k1 = p01 / sp
    return x + k0 * e, v + k1 * e, k0 * r, k1 * r, p11 - k1 * p01


class RangeFilter:
    """Turns raw readings into published estimates; pure, one call per frame.

    Not thread-safe: one instance per sensor, called from the read loop. State:
    ``x``, ``v``, ``p00``, ``p01``, ``p11`` (the track: metres, m/s and their
    covariance), ``noise_fast``, ``noise_light`` and ``noise_slow`` (the noise
    statistic A of noise.py, metres: winsorised; truncated, for the light; its slow
    average, which ``_slow_of_slow`` averages again to see its lag on a ramp),
    ``c2`` (c^2 from the fast one, m^2), ``lux`` (L_hat, lux, or None
    where it cannot be observed), ``qa`` (the process noise in force, m^2/s^3),
    ``weak``/``out_of_range``/``ambient`` (policy.py's latches), ``zone`` (the last
    published zone, for zone.py's hysteresis).
    """

    __slots__ = (
        "_amp_strong",
        "_amp_strong_again",
        "_boot",
        "_boot_ok",
        "_boot_track",
        "_boot_until_ns",
        "_c2_floor",
        "_chained",
        "_clip_a",
        "_clip_step",
        "_confirm",
        "_cut_a",
        "_drift_gain",
        "_drift_noise",
        "_drift_thr2",
        "_fast_keep",
        "_fast_w",
        "_floor",
        "_gap",
        "_gap_prev",
        "_gate2",
        "_hold",
        "_hold_frames",
        "_holding",
        "_inv_k",
        "_jump",
        "_kA",
        "_kL",
        "_last_accept_ns",
        "_last_t_ns",
        "_latched",
        "_learn_below",
        "_learn_rising",
        "_links",
        "_lux_enter",
        "_lux_exit",
        "_m1",
        "_man_gain",
        "_man_noise",
        "_max_feed",
        "_max_in",
        "_max_m",
        "_mid_m",
        "_min_in",
        "_min_m",
        "_mt",
        "_obs2",
        "_outlier_drop2",
        "_q_m2",
        "_qa_hi",
        "_qa_lo",
        "_quiet_ns",
        "_refresh_ticks",
        "_run_amp",
        "_run_away",
        "_run_ended_ns",
        "_run_gap",
        "_run_last",
        "_run_mixed",
        "_run_n",
        "_run_r",
        "_run_rsum",
        "_run_same",
        "_run_side",
        "_run_sign",
        "_run_sum",
        "_sh_left",
        "_sh_llr",
        "_sh_on",
        "_sh_p00",
        "_sh_p01",
        "_sh_p11",
        "_sh_t_ns",
        "_sh_v",
        "_sh_x",
        "_sigma0",
        "_slow_keep",
        "_slow_of_slow",
        "_slow_restart_w",
        "_slow_tick",
        "_slow_w",
        "_span_frames",
        "_span_i",
        "_span_k",
        "_span_min",
        "_span_mins",
        "_spans_seen",
        "_stale_ns",
        "_still_ns",
        "_thr2",
        "_track_s",
        "_trend_hold",
        "_trend_run",
        "_unrel2",
        "_v0var",
        "_z1",
        "_z2",
        "_zone_limits",
        "active",
        "ambient",
        "c2",
        "config",
        "drift",
        "extra",
        "inv_amp_ref",
        "lux",
        "man_mean",
        "man_power",
        "noise_fast",
        "noise_light",
        "noise_slow",
        "out_of_range",
        "p00",
        "p01",
        "p11",
        "qa",
        "v",
        "weak",
        "x",
        "zone",
    )

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = c = config or FilterConfig()
        h = c.hysteresis
        self.inv_amp_ref = inv_amp_ref = 1.0 / c.amp_ref
        self._q_m2 = c.resolution_m * c.resolution_m / 12.0
        self._stale_ns = round(c.stale_after_s * 1e9)
        self._floor = c.sigma_floor_m
        self._min_m = c.min_range_m
        self._max_m = c.max_range_m
        self._mid_m = 0.5 * (c.min_range_m + c.max_range_m)
        # Gates (policy.py).
        self._amp_strong = first_amp_at_least(c.amp_min, c.s_min, inv_amp_ref)
        self._amp_strong_again = first_amp_at_least(
            band_edge(c.amp_min, h), band_edge(c.s_min, h), inv_amp_ref
        )
        self._min_in = c.min_range_m + c.range_hysteresis_m
        self._max_in = c.max_range_m - c.range_hysteresis_m
        self._max_feed = c.max_range_m + c.range_feed_margin_m
        self._lux_enter = c.lux_high_ambient
        self._lux_exit = c.lux_high_ambient * (1.0 - h)
        # Tracker.
        self._qa_lo = c.accel_psd
        self._qa_hi = max(c.manoeuvre_accel_psd, c.accel_psd)
        self._gate2 = c.gate_sigmas * c.gate_sigmas
        self._confirm = c.step_confirm
        self._v0var = c.init_speed_sigma_m_s * c.init_speed_sigma_m_s
        rho = 1.0 - 1.0 / c.manoeuvre_frames
        self._man_gain = 1.0 - rho
        self._man_noise = (1.0 - rho) / (1.0 + rho)
        self._thr2 = c.manoeuvre_sigmas * c.manoeuvre_sigmas * self._man_noise
        rho = 1.0 - 1.0 / (DRIFT_SPAN * c.manoeuvre_frames)
        self._drift_gain = 1.0 - rho
        self._drift_noise = (1.0 - rho) / (1.0 + rho)
        self._drift_thr2 = DRIFT_SIGMAS * DRIFT_SIGMAS * self._drift_noise
        self._hold_frames = c.manoeuvre_frames
        self._unrel2 = c.sigma_unreliable_m * c.sigma_unreliable_m
        self._outlier_drop2 = 4.0 * self._unrel2
        # Noise (noise.py).
        self._sigma0 = c.sigma0_m
        self._inv_k = 1.0 / c.k_m_per_lux
        m1 = winsorised_abs_mean(c.noise_clip_sigmas)
        self._m1 = m1
        self._clip_a = c.noise_clip_sigmas / m1
        # The clip is never below noise_clip_sigmas times d2's scatter for the output
        # step's noise alone (noise.py, "A still, quantised target").
        self._clip_step = c.noise_clip_sigmas * d2_scale(0.0, self._q_m2)
        self._kA = 1.0 / (6.0 * m1 * m1)
        mt = truncated_abs_mean(LIGHT_CUT_SIGMAS)
        self._mt = mt
        self._cut_a = LIGHT_CUT_SIGMAS / mt
        self._kL = 1.0 / (6.0 * mt * mt)
        self._fast_keep = 1.0 / c.noise_frames
        # The slow side sees one sample in SLOW_EVERY: its weights count readings.
        self._slow_keep = min(1.0, SLOW_EVERY / c.noise_slow_frames)
        self._trend_hold = max(1, round(c.noise_slow_frames / SLOW_EVERY))
        self._slow_restart_w = min(1.0, SLOW_EVERY / (SLOW_RESTART_SPANS * c.noise_frames))
        self._span_frames = max(1, round(c.noise_frames / SLOW_EVERY))
        # After a stretch where the light cannot be seen, the slow side waits until the
        # light's fast average has taken LIGHT_WAIT_SPANS spans of the new readings
        # (noise.py).
        self._refresh_ticks = LIGHT_WAIT_SPANS * c.noise_frames
        # The boot ends on the NOISE_BOOT_SAMPLES-th sample of the fast average's running
        # start, which lasts while its weight 1 / (FAST_PRIOR_READINGS + k) is above
        # 1 / noise_frames: a shorter average has no boot.
        self._boot_ok = c.noise_frames > FAST_PRIOR_READINGS + NOISE_BOOT_SAMPLES
        self._jump = c.noise_jump_ratio
        self._obs2 = c.lux_observable_sigma_m * c.lux_observable_sigma_m
        self._c2_floor = 0.01 * c.sigma0_m * c.sigma0_m
        self._zone_limits = ZoneLimits.from_config(c)  # step applies them inline
        self.reset()

    def reset(self) -> None:
        """Forget all state (after a reconnect)."""
        c = self.config
        self.weak = self.out_of_range = self.ambient = self._latched = False
        self.active = False
        self.x = self.v = self.p00 = self.p01 = self.p11 = 0.0
        self.qa = self._qa_lo
        self._hold = 0
        self.man_mean = self.drift = self.extra = 0.0
        self.man_power = 1.0
        self._still_ns = self._quiet_ns = _NEVER
        self._sh_on = False
        self._sh_x = self._sh_v = self._sh_p00 = self._sh_p01 = self._sh_p11 = 0.0
        self._sh_llr = 0.0
        self._sh_t_ns = self._sh_left = 0
        self._run_n = self._run_away = self._run_side = 0
        self._run_sum = self._run_rsum = self._run_last = self._run_r = 0.0
        self._run_sign = self._run_mixed = False
        self._run_amp = 0
        self._track_s = 0.0  # the track's amp as S; the first track's first reading sets it
        self._run_same = False  # every amp of the run on the track's surface
        self._run_gap = 0
        self._run_ended_ns = _NEVER  # the frame whose reading ended a run of outliers
        c0 = c.sigma0_m + c.k_m_per_lux * c.lux_init
        self.c2 = c0 * c0
        self.noise_fast = self.noise_light = self.noise_slow = self._slow_of_slow = 0.0
        self._slow_w = 1.0  # its first sample replaces the prior: a running mean
        self._fast_w = 1.0 / (1.0 + FAST_PRIOR_READINGS)
        self._span_mins = [_INF] * MIN_STATS_SPANS
        self._span_min = _INF
        self._learn_below = self._learn_rising = _INF  # no floor yet: learn everything
        self._span_i = 0
        self._spans_seen = 0
        self._span_k = self._span_frames
        # The light's fast average starts from the prior: the slow side waits, as after
        # a stretch where the light cannot be seen, for LIGHT_WAIT_SPANS of its spans.
        self._slow_tick = self._refresh_ticks
        self._trend_run = 0  # slow samples in a row with the lag beyond its gate, signed
        self.lux: float | None = None
        self._z1 = self._z2 = 0.0  # the last two readings, metres, where _links says
        self._links = 0  # how many of _z1, _z2 hold readings of the present chain
        self._gap = self._gap_prev = 0
        # _links == 2 and no frame missed since _z2: the per-frame path's one test
        self._chained = False
        self._boot: list[float] | None = [] if self._boot_ok else None
        self._boot_track: list[tuple[float, float, int]] | None = [] if self._boot_ok else None
        self._boot_until_ns = _NEVER
        self._holding = self._boot_ok  # no boot: nothing to hold
        self.zone = _UNRELIABLE
        self._last_t_ns: int | None = None
        self._last_accept_ns = 0

    def assume_reading_sigma(self, sigma_m: float, amp: int) -> None:
        """Take ``sigma_m`` (metres) as the noise of the next reading, of strength
        ``amp``, as if the fast noise average had measured it: the reading variance r
        of ``step`` is then the one given (to within the next sample's weight in the
        average, 1 / ``noise_frames``), while the light is still read from the
        readings. For ``lunad eval --true-noise``, which tells lunad's tracker the
        simulator's noise, as the oracle is told it, to separate what learning the
        noise costs from what the tracker costs; the daemon never calls it. A noise told
        needs no boot (noise.py): the estimate is published from the first reading."""
        if amp <= 0:
            raise ValueError(f"assume_reading_sigma: amp must be above 0, got {amp!r}")
        self._boot = self._boot_track = None
        self._holding = False
        s = amp * self.inv_amp_ref
        c2 = sigma_m * sigma_m * s * s
        self.c2 = c2 if c2 > self._c2_floor else self._c2_floor
        if self.noise_fast:  # the averages exist (from a chain's second reading on)
            self.noise_fast = self._m1 * d2_scale(self.c2, self._q_m2 * s * s)
            self._fast_w = self._fast_keep

    def step(self, raw_m: float | None, amp: int, t_mono_ns: int) -> Estimate:
        """Clean one reading.

        Args:
            raw_m: distance the sensor reported, metres, or None when it reported none.
            amp: the sensor's signal strength.
            t_mono_ns: monotonic receive time, nanoseconds.

        Returns:
            The estimate to publish for this frame.
        """
        t = t_mono_ns
        s = amp * self.inv_amp_ref
        last = self._last_t_ns
        if last is None:
            self._last_t_ns = self._last_accept_ns = t
            dt = 0.0
        elif t >= last:
            self._last_t_ns = t
            dt = (t - last) * 1e-9
        elif last - t > self._stale_ns:  # a clock started again: a recording across a
            self.reset()  # reboot; start afresh, as the daemon did after it
            self._last_t_ns = self._last_accept_ns = t
            dt = 0.0
        else:  # stamped before the last frame: taken as at its time, not counted twice
            t = last
            dt = 0.0

        # Gates with hysteresis (policy.py).
        z: float | None  # the reading, when it may feed the filter
        marginal = False  # a reading in the weak gate's hysteresis band: degraded
        reasons: tuple[Reason, ...]
        if (  # the common frame: no latch set, strong enough and in range
            not self._latched
            and raw_m is not None
            and amp >= self._amp_strong
            and amp <= AMP_AMBIENT
            and raw_m >= self._min_m
            and raw_m <= self._max_m
        ):
            z = raw_m
            reasons = _NONE
        elif amp > AMP_AMBIENT:
            z = None
            reasons = _SATURATED if amp == AMP_SATURATED else _AMBIENT
        else:
            z = None
            weak = amp < (self._amp_strong_again if self.weak else self._amp_strong)
            self.weak = weak
            if raw_m is None:
                reasons = _WEAK if weak else _NO_DISTANCE
            else:
                if self.out_of_range:
                    out = raw_m < self._min_in or raw_m > self._max_in
                else:
                    out = raw_m < self._min_m or raw_m > self._max_m
                self.out_of_range = out
                # Not weak and not out imply both (their hysteresis bands lie inside):
                # the common frame pays for neither bound.
                if (not weak or amp >= self._amp_strong) and (
                    not out or self._min_m <= raw_m <= self._max_feed
                ):
                    z = raw_m
                if out:
                    close = raw_m < self._mid_m
                    if weak:
                        reasons = _WEAK_CLOSE if close else _WEAK_FAR
                    else:
                        reasons = _CLOSE if close else _FAR
                elif weak and z is None:
                    reasons = _WEAK
                else:  # weak with a reading: the amp is in the band above the threshold
                    marginal = weak
                    reasons = _NONE
            self._latched = weak or self.out_of_range  # the common frame tests one flag

        outlier_e = 0.0
        active = self.active
        if z is not None:
            # The noise, from the second differences of the raw readings (noise.py).
            s2 = s * s
            z1 = self._z1
            self._z1 = z
            if self._chained:  # readings on the last two frames: the plain difference
                d: float | None = z - 2.0 * z1 + self._z2
                self._z2 = z1
            else:
                d = self._second_difference(z, z1, s2)
            if d is not None:
                y = (d if d >= 0.0 else -d) * s
                w = self._fast_w
                if w > self._fast_keep:  # still a running mean, after a start
                    w = self._learning(y, s2, w, last)
                light = self.noise_light
                fast = self.noise_fast
                lim = self._clip_a * fast
                if y > lim:  # clipped: and beyond the light's cut, not light at all
                    if y < self._cut_a * light:
                        self.noise_light = light + w * (y - light)
                    q_lim = self._clip_step * s
                    if lim < q_lim:  # a one-step difference counts whole
                        lim = q_lim if y > q_lim else y
                    y = lim
                else:
                    self.noise_light = light + w * (y - light)
                fast += w * (y - fast)
                self.noise_fast = fast
                qs2 = self._q_m2 * s2
                c2 = fast * fast * self._kA - qs2
                self.c2 = c2 if c2 > self._c2_floor else self._c2_floor
                obs = self._obs2 * s2
                if c2 < obs:  # below the output step: not observable,
                    self.lux = None  # and the slow average keeps what it last saw,
                    # until the fast one is fresh; near the bound, where one frame
                    # in a few is unobservable, the light is then not read at all
                    self._slow_tick = self._refresh_ticks
                else:
                    tick = self._slow_tick - 1
                    if tick:  # the slow side samples the fast one (SLOW_EVERY)
                        self._slow_tick = tick
                    else:
                        self._slow_tick = SLOW_EVERY
                        self._slow_side(self.noise_light, qs2, obs)
            r = self.c2 / s2 + self._q_m2
            if not active or t - self._last_accept_ns > self._stale_ns:
                # No track yet, or none accepted for stale_after_s: start one here
                # (the short branch first: see the range test below).
                if active and t >= self._quiet_ns:  # the track as it was, at the last frame
                    self._shadow(self.x, self.v, self.p00, self.p01, self.p11, t, last)
                else:  # a still track judged beside a manoeuvre ends with the track
                    self._sh_on = False
                self._start(z, r)
                self._last_accept_ns = t
                if active:  # after a stale stretch: held back until a reading agrees
                    reasons = (*reasons, Reason.STALE) if reasons else _STALE
                else:  # the first track: its surface's amp, and the noise has until
                    self._track_s = s  # then to be measured
                    if self._boot is not None:
                        self._boot_until_ns = t + self._stale_ns
            else:
                x = self.x
                p00 = self.p00
                p01 = self.p01
                p11 = self.p11
                if dt > 0.0:
                    qd = self.qa * dt
                    qdt = qd * dt
                    dp = dt * p11
                    x += self.v * dt
                    p00 += dt * (2.0 * p01 + dp + qdt * (1.0 / 3.0))
                    p01 = p01 + dp + 0.5 * qdt
                    p11 = p11 + qd
                e = z - x
                sp = p00 + r
                e2 = e * e
                if e2 > self._gate2 * sp:  # beyond the gate (a method: the jump is short)
                    outlier_e = self._reject(z, amp, s, r, e, sp, x, p00, p01, p11, t)
                else:
                    ts = self._track_s
                    self._track_s = ts + TRACK_AMP_GAIN * (s - ts)
                    if self._run_n:
                        self._run_n = 0
                        self._run_ended_ns = t
                    if self._sh_on and self._shadow_step(z, r, e2, sp, t):
                        # The still track explains the readings as well: it is the track,
                        # settled, and the innovation means were the other track's.
                        x = self._sh_x
                        self.v = self._sh_v
                        p00 = self._sh_p00
                        p01 = self._sh_p01
                        p11 = self._sh_p11
                        e = z - x
                        sp = p00 + r
                        e2 = e * e
                        self.man_mean = self.drift = 0.0
                        self._hold = 0
                        self.qa = self._qa_lo
                        self._still_ns = self._quiet_ns = t
                    k0 = p00 / sp
                    k1 = p01 / sp
                    self.x = x + k0 * e
                    self.v += k1 * e
                    self.p00 = k0 * r  # p00 - k0 p00, as p00 r / sp
                    p11 = p11 - k1 * p01
                    if p11 < 0.0:  # float rounding at extreme settings
                        self.p01 = self.p11 = 0.0
                    else:
                        self.p01 = k1 * r  # p01 - k0 p01
                        self.p11 = p11
                    self._last_accept_ns = t
                    # Manoeuvre test: a bias in the innovations that their spread
                    # cannot explain switches the process noise up while it lasts.
                    mean = self.man_mean
                    mean += self._man_gain * (e - mean)
                    self.man_mean = mean
                    drift = self.drift
                    drift += self._drift_gain * (e - drift)
                    self.drift = drift
                    power = self.man_power
                    power += self._drift_gain * (e2 - power)
                    self.man_power = power
                    mean2 = mean * mean
                    drift2 = drift * drift
                    excess = mean2 - self._man_noise * power  # m^2 less its scatter's share
                    if (
                        mean2 > self._thr2 * power
                        and (  # on a still track, not while the noise rises
                            self.v * self.v >= _STILL_V2 or self.noise_light <= self._learn_below
                        )
                    ) or drift2 > self._drift_thr2 * power:
                        # the still track is judged beside the hold (SHADOW_FRAMES)
                        self._shadow(self.x, self.v, self.p00, self.p01, self.p11, t)
                        if not self._hold and excess > 0.0:
                            # A manoeuvre begins: the raised qa reaches P00 only over
                            # several frames, so P takes in the lag the fast mean shows
                            # now and the gain rises from the next reading on. This
                            # frame's sigma counts it twice (here and in ``extra``).
                            self.p00 += excess
                        self._hold = self._hold_frames
                        self.qa = self._qa_hi
                        self._still_ns = self._quiet_ns = _NEVER
                    elif self._hold:  # a manoeuvre lasts: hold, as for a fresh track
                        hold = self._hold - 1
                        self._hold = hold
                        if not hold:
                            self.qa = self._qa_lo
                            self._settle(t, r, dt)
                    # What P cannot see: the part of the innovations' running means
                    # that their own scatter does not explain is a bias of the track.
                    extra = excess if excess > 0.0 else 0.0
                    excess = drift2 - self._drift_noise * power
                    if excess > 0.0:
                        extra += excess
                    if e2 > _COVER2 * sp:  # a reading the track does not explain yet
                        extra += COVER_SHARE * e2
                    self.extra = extra
        else:
            self._gap += 1
            self._chained = False
            if active:
                if self._run_n:
                    gap = self._run_gap + 1
                    self._run_gap = gap
                    if gap > RUN_GAP_MAX:
                        self._run_n = 0
                if dt > 0.0:
                    self._predict(dt)

        # Publish or not, ambient flag and zone.
        if outlier_e:
            if marginal:  # a marginal reading the track does not explain
                reasons = _WEAK_OUTLIER
            elif outlier_e * outlier_e > self._outlier_drop2:  # a sigma that covers it
                reasons = _OUTLIER  # would say "unreliable": the robot gets no figure
        if self._holding:
            # A start: no estimate while the noise is not measured (noise.py) or the first
            # track's own sigma is beyond usable, for at most stale_after_s from its start.
            boot_track = self._boot_track
            if boot_track is not None and z is not None:  # the boot's readings, for _refilter
                if t < self._boot_until_ns and len(boot_track) < BOOT_TRACK_READINGS:
                    boot_track.append((z, s2, t))
                else:  # a boot this long is scaled instead: it keeps nothing more
                    self._boot_track = None
            if not reasons:
                if t >= self._boot_until_ns:
                    self._holding = False
                elif self._boot is not None or self.p00 > self._unrel2:
                    reasons = _WEAK_STALE if marginal else _STALE
        if not reasons and self.active:
            x = self.x
            # The short branch first: Python 3.11 specialises a comparison only where
            # a short jump follows it, and the gate's test and this one ran generic
            # while they jumped over the long branch (docs/performance.md).
            if x < self._min_m or x > self._max_m:
                reasons = _CLOSE if x < self._min_m else _FAR
            else:
                var = self.p00
                if t >= self._still_ns:  # settled after a manoeuvre
                    var *= STILL_VAR_RATIO
                if outlier_e:  # the zone describes conditions: the track's own sigma
                    zsig = sqrt(self.p00)
                    if zsig < self._floor:
                        zsig = self._floor
                    sigma = sqrt(var + COVER_SHARE * outlier_e * outlier_e)
                    if sigma < self._floor:
                        sigma = self._floor
                else:
                    zsig = sigma = sqrt(var + self.extra)
                    if sigma < self._floor:
                        zsig = sigma = self._floor
                lux_out = self.lux
                if lux_out is None:
                    ambient = self.ambient = False
                    lux_zone = 0.0
                else:
                    lux_zone = lux_out
                    if self.ambient:
                        ambient = self.ambient = lux_out > self._lux_exit
                    else:
                        ambient = self.ambient = lux_out > self._lux_enter
                # The zone, with hysteresis (zone.py: ZoneClassifier.classify).
                zone = self.zone
                zl = self._zone_limits
                if zone is _UNRELIABLE:
                    if (
                        lux_zone < zl.lux_unrel_leave
                        and s >= zl.s_unrel_leave
                        and zsig <= zl.sig_unrel_leave
                    ):
                        zone = self.zone = (
                            _STABLE
                            if lux_zone < zl.lux_stable
                            and s >= zl.s_stable
                            and zsig <= zl.sig_stable
                            else _MARGINAL
                        )
                elif lux_zone > zl.lux_unrel or s < zl.s_unrel or zsig > zl.sig_unrel:
                    zone = self.zone = _UNRELIABLE
                elif zone is _STABLE:
                    if not (
                        lux_zone < zl.lux_stable_stay
                        and s >= zl.s_stable_stay
                        and zsig <= zl.sig_stable_stay
                    ):
                        zone = self.zone = _MARGINAL
                elif lux_zone < zl.lux_stable and s >= zl.s_stable and zsig <= zl.sig_stable:
                    zone = self.zone = _STABLE
                if outlier_e:
                    reasons = _OUTLIER_AMBIENT if ambient else _OUTLIER
                elif zone is _UNRELIABLE:  # ok only where the paper's model holds
                    if z is not None and (self._gap_prev or self._run_ended_ns == t):
                        d = x - z
                        if d * d > self._outlier_drop2:
                            # Back after frames it did not take and 20 cm from its
                            # reading: a track that coasted past the readings (a
                            # sweep's far corner) gets no figure, as an outlier's
                            # does (above; docs/filter.md section 5).
                            reasons = _WEAK_OUTLIER if marginal else _OUTLIER
                            return _new(Estimate, (None, None, lux_out, s, _DROPOUT, reasons, zone))
                    reasons = _AMBIENT_UNRELIABLE if ambient else _UNRELIABLE_ZONE
                elif ambient:
                    reasons = _AMBIENT
                elif not marginal:
                    return _new(Estimate, (x, sigma, lux_out, s, _OK, _NONE, zone))
                if marginal:
                    reasons = (Reason.WEAK_SIGNAL, *reasons) if reasons else _WEAK
                return _new(Estimate, (x, sigma, lux_out, s, _DEGRADED, reasons, zone))
        self.zone = _UNRELIABLE
        if t - self._last_accept_ns > self._stale_ns:
            reasons = (*reasons, Reason.STALE) if reasons else _STALE
        return _new(Estimate, (None, None, self.lux, s, _DROPOUT, reasons, _UNRELIABLE))

    def _reject(
        self,
        z: float,
        amp: int,
        s: float,
        r: float,
        e: float,
        sp: float,
        x: float,
        p00: float,
        p01: float,
        p11: float,
        t: int,
    ) -> float:
        """Take the reading ``z`` (metres, variance ``r``, m^2; amp ``amp``, strength
        ``s``, at ``t`` ns) that the track rejected: its innovation ``e`` (metres) lies
        beyond the gate of its predicted variance ``sp`` (m^2), the track predicted to
        ``x`` with covariance ``p00``, ``p01``, ``p11``. Counts it into the run of
        readings that agree with each other and not with the track, and starts the
        track on that run once it is confirmed (or at the latest reading, at an
        edge); else the track keeps its prediction. Returns the outlier's innovation
        for the publishing step: ``e``, ``_UNCONFIRMED`` for a start it may not
        publish as ok, or 0.0 for a start on readings that agree."""
        # The manoeuvre test's mean square takes the rejected reading at the gate: after
        # a jump of the light, readings fall beyond the gate while the reading variance
        # still climbs, and the accepted ones alone leave the mean square behind the new
        # noise that the fast mean already shows (docs/filter.md section 4).
        power = self.man_power
        self.man_power = power + self._drift_gain * (self._gate2 * sp - power)
        sign = e > 0.0
        d = z - self._run_last
        n = self._run_n
        away = self._run_away
        side = self._run_side + 1 if n and sign == self._run_sign else 1
        self._run_side = side
        ts = self._track_s  # the surface the track is on (TRACK_AMP_GAIN)
        same = abs(s - ts) < SAME_AMP_SHARE * ts
        if n and sign == self._run_sign and d * d <= self._gate2 * (r + self._run_r):
            n += 1
            same = same and self._run_same
            self._run_sum += z
            self._run_rsum += r
            away = 0
            ra = self._run_amp
            if amp > EDGE_AMP_RATIO * ra or ra > EDGE_AMP_RATIO * amp:
                self._run_mixed = True
        else:
            if n and sign == self._run_sign and (d > 0.0) == sign:
                away = (away or 1) + 1  # each further off than the last
            else:
                away = 0
            n = 1
            self._run_sum = z
            self._run_rsum = r
            self._run_sign = sign
            self._run_mixed = False
        self._run_away = away
        self._run_amp = amp
        self._run_last = z
        self._run_r = r
        self._run_gap = 0
        self._run_same = same
        if n >= self._confirm and (  # on the same surface, a still track waits
            n > self._confirm  # for one more (SAME_AMP_SHARE)
            or not same
            or self.v * self.v >= _STILL_V2
        ):
            self._shadow(x, self.v, p00, p01, p11, t)  # the track as it was
            self._start(self._run_sum / n, self._run_rsum / (n * n))
            self._last_accept_ns = t
            if self._run_mixed:
                return _UNCONFIRMED
        elif away >= EDGE_RUN or side >= SIDE_RUN:  # an edge: start at the latest
            self._shadow(x, self.v, p00, p01, p11, t)
            self._start(z, r)
            self._last_accept_ns = t
            return _UNCONFIRMED
        else:
            self._run_n = n
            self.x = x
            self.p00 = p00
            self.p01 = p01
            self.p11 = p11
            return e
        return 0.0

    def _second_difference(self, z: float, z1: float, s2: float) -> float | None:
        """The second difference (metres) of the readings ending at ``z`` where the last
        two frames did not both bring one: bridged over up to ``MAX_GAP_FRAMES`` frames
        without a reading (``GAP_NORMALISERS``, noise.py), or None where the chain of
        readings starts again; its first pair seeds the fast noise average with the
        configured prior (``s2`` is S^2 of ``z``). Keeps the chain: ``_z2``,
        ``_links``, ``_gap`` and ``_gap_prev`` (the frames missing before ``z``), and
        ``_chained`` (the next reading, one frame on, takes the plain difference)."""
        gap = self._gap
        self._gap = 0
        gap_prev = self._gap_prev
        self._gap_prev = gap
        z2 = self._z2
        links = self._links
        if not links or gap >= MAX_GAP_FRAMES:  # z starts the chain
            self._links = 1
            self._chained = False
            return None
        self._z2 = z1
        self._chained = not gap
        if links == 1:
            self._links = 2
            if self.noise_fast == 0.0:  # the first pair: the configured prior
                sd = d2_scale(self.c2, self._q_m2 * s2)
                self.noise_fast = self._m1 * sd
                self.noise_light = self._mt * sd  # the slow one: its first sample
            return None
        if gap or gap_prev:  # bridged over the missing frames
            g1 = gap + 1
            g2 = gap_prev + 1
            return ((z - z1) / g1 - (z1 - z2) / g2) * GAP_NORMALISERS[g1][g2]
        return z - 2.0 * z1 + z2

    def _learning(self, y: float, s2: float, w: float, t_state: int | None) -> float:
        """Take the sample ``y`` (|d2| S, metres) while the fast noise average is still a
        running mean (after a start), and return its weight ``w`` in the averages.
        The ``NOISE_BOOT_SAMPLES``-th sample after a start ends the boot (noise.py):
        the fast average starts again from the samples' median, counted as that many
        readings, and the first track runs again over the readings it took with the
        new reading variance (``_refilter``), a run of outliers pending among them;
        where it cannot (the boot outlasted ``stale_after_s`` or
        ``BOOT_TRACK_READINGS``), its covariance, built with the prior's variance, is
        scaled to the new one.
        ``s2`` is S^2 of the reading and ``t_state`` (ns) the time the track stands
        at, the last frame's."""
        boot = self._boot
        if boot is not None:
            boot.append(y)
            if len(boot) >= NOISE_BOOT_SAMPLES:
                self._boot = None
                sd = sorted(boot)[len(boot) // 2] * _INV_NORMAL_MEDIAN_ABS
                qs2 = self._q_m2 * s2
                c2 = sd * sd * (1.0 / 6.0) - qs2
                if c2 < self._c2_floor:
                    c2 = self._c2_floor
                    sd = d2_scale(c2, qs2)
                if self.active:
                    boot_track = self._boot_track
                    if boot_track:
                        self._run_n = 0  # the run's readings are among the boot's
                        self._refilter(boot_track, c2, t_state)
                    else:
                        ratio = (c2 + qs2) / (self.c2 + qs2)  # r_new / r_old: the same S
                        self.p00 *= ratio
                        self.p01 *= ratio
                        self.p11 *= ratio
                self._boot_track = None
                self.c2 = c2
                self.noise_fast = self._m1 * sd
                w = 1.0 / (1.0 + NOISE_BOOT_SAMPLES)
        self._fast_w = w / (1.0 + w)
        return w

    def _refilter(
        self, readings: list[tuple[float, float, int]], c2: float, t_state: int | None
    ) -> None:
        """Run the first track again over ``readings``, the ones it took during the boot
        (metres, S^2 and nanoseconds each), now that the boot has measured the noise
        ``c2`` (c^2, m^2): its state and covariance become those of a track that knew
        the noise from its first reading, brought to ``t_state`` (ns, the last frame's
        time). The track ran on the prior's noise meanwhile; under 60 klux that is about
        five times too quiet, and its hold (``manoeuvre_frames`` readings at
        ``manoeuvre_accel_psd``) took the scatter of its first readings for a speed of
        metres a second, which the process noise after the hold is too small to undo
        for a second or more. It runs again at ``accel_psd`` from its first reading,
        with no hold, from a speed prior of ``BOOT_SPEED_SIGMA_M_S``: the boot's
        readings cannot tell its speed under heavy noise. A reading beyond
        ``gate_sigmas`` of the track is left out and ``step_confirm`` of them in a row
        start it again, as the track would have; fewer at the end start no run (the
        track's pending one is dropped: its readings are among these, judged again
        against the new track). The innovation means start again."""
        q = self._q_m2
        gate2 = self._gate2
        qa = self._qa_lo
        x, s2, t_prev = readings[0]
        v = p01 = dt = 0.0
        p00 = r = c2 / s2 + q
        p11 = _BOOT_V0VAR
        confirm = self._confirm
        out = 0
        for z, s2, t in readings[1:]:
            dt = (t - t_prev) * 1e-9
            if dt > 0.0:
                x, p00, p01, p11 = _cv_predicted(x, v, p00, p01, p11, qa, dt)
                t_prev = t
            r = c2 / s2 + q
            e = z - x
            sp = p00 + r
            if e * e > gate2 * sp:
                out += 1
                if out >= confirm:
                    out = 0
                    x = z
                    v = p01 = 0.0
                    p00 = r
                    p11 = _BOOT_V0VAR
                continue
            out = 0
            x, v, p00, p01, p11 = _cv_updated(x, v, p00, p01, p11, e, sp, r)
        if t_state is not None and t_state > t_prev:
            x, p00, p01, p11 = _cv_predicted(x, v, p00, p01, p11, qa, (t_state - t_prev) * 1e-9)
        self.x = x
        self.v = v
        self.p00 = p00
        self.p01 = p01
        self.p11 = p11 if p11 > 0.0 else 0.0
        self.man_mean = self.drift = self.extra = 0.0
        self.man_power = r
        self._hold = 0
        self.qa = qa
        self._settle(t_prev, r, dt)

    def _slow_side(self, fast: float, qs2: float, obs: float) -> None:
        """Feed ``fast``, the fast average that the light is read from (``noise_light``,
        metres), to the minimum statistics and the slow average, and work out ``lux``
        from the slow one (noise.py). ``qs2`` is the output step's variance times S^2
        and ``obs`` the least observable c^2 at this reading's S, both m^2. Runs on
        one observable reading in ``SLOW_EVERY``."""
        # Minimum statistics: the fast average's minimum over the last
        # MIN_STATS_SPANS spans is the floor clutter cannot lift.
        if fast < self._span_min:
            self._span_min = fast
        slow = self.noise_slow
        slow2 = self._slow_of_slow
        # Nothing on top of the noise; while a still track's light is seen rising, the
        # floor lags the ramp and the bound is wider (RISING_LEARN_NEAR in noise.py).
        if fast <= self._learn_below or (self._trend_run > 1 and fast <= self._learn_rising):
            w = self._slow_w
            slow += w * (fast - slow)
            slow2 += w * (slow - slow2)
            if w > self._slow_keep:  # a running mean until it spans enough
                self._slow_w = w / (1.0 + w)
        if slow > self._jump * fast:  # the light fell
            slow = slow2 = fast
            self._slow_w = self._slow_restart_w
        k = self._span_k - 1
        if k:
            self._span_k = k
        else:
            rose = self._end_span(slow)
            if rose:  # the light rose: both start again (_end_span says from what)
                slow = slow2 = rose
        self.noise_slow = slow
        self._slow_of_slow = slow2
        # The slow average's lag on a ramp of light, beyond what it scatters by; on a
        # still track, a gate that narrows once the lag has held beyond it for longer
        # than a slow average's span (SLOW_TREND_GATE in noise.py).
        lag = slow - slow2
        gate = SLOW_TREND_GATE * slow
        if lag > gate or -lag > gate:
            side = 1 if lag > 0.0 else -1
            run = self._trend_run * side  # > 0: the run so far is on this side
            run = run + 1 if run > 0 and self.v * self.v < _STILL_V2 else 1
            self._trend_run = run * side
            if run > self._trend_hold:
                gate *= self._trend_hold / run
            slow += lag - side * gate
        elif self._trend_run:
            self._trend_run = 0
        c2 = slow * slow * self._kL - qs2
        if c2 < obs or self._spans_seen < LIGHT_MEASURED_SPANS:
            self.lux = None
        else:
            lux = (sqrt(c2) - self._sigma0) * self._inv_k
            self.lux = lux if lux > 0.0 else 0.0

    def _end_span(self, slow: float) -> float:
        """Close a span of the minimum statistics (every ``noise_frames`` observable
        readings): the floor becomes the least span minimum of the last
        ``MIN_STATS_SPANS``. When even the floor rose ``SLOW_RISE_RATIO`` above the slow
        average ``slow`` (the light rose), returns the value the slow average starts
        again from: the newest span's minimum (noise.py); until the light's first
        figure, the floor's mean, at ``SLOW_RISE_START``. Else 0."""
        seen = self._spans_seen
        i = self._span_i
        mins = self._span_mins
        newest = self._span_min
        mins[i] = newest
        self._span_i = i + 1 if i + 1 < MIN_STATS_SPANS else 0
        self._span_min = _INF
        self._span_k = self._span_frames
        floor = min(mins) * _INV_MIN_STATS_BIAS
        self._learn_below = MIN_STATS_NEAR * floor
        self._learn_rising = RISING_LEARN_NEAR * floor
        if seen < LIGHT_MEASURED_SPANS:
            self._spans_seen = seen + 1
            rise, restart = SLOW_RISE_START, floor
        else:
            rise, restart = SLOW_RISE_RATIO, newest
        if floor > rise * slow:
            self._slow_w = self._slow_restart_w
            return restart
        return 0.0

    def _start(self, z_m: float, r_m2: float) -> None:
        """Begin a track at ``z_m`` (variance ``r_m2``) with unknown speed."""
        self._trend_run = 0  # a new surface: its noise's trend is not the light's
        self.active = True
        self.x = z_m
        self.v = 0.0
        self.p00 = r_m2
        self.p01 = 0.0
        self.p11 = self._v0var
        self._run_n = 0
        self.qa = self._qa_hi
        self._hold = self._hold_frames
        self.man_mean = self.drift = self.extra = 0.0
        self.man_power = r_m2
        self._still_ns = self._quiet_ns = _NEVER

    def _shadow(
        self,
        x: float,
        v: float,
        p00: float,
        p01: float,
        p11: float,
        t: int,
        t_state: int | None = None,
    ) -> None:
        """Keep the track ``x``, ``v`` (metres, m/s) with covariance ``p00``, ``p01``,
        ``p11``, which stands at ``t_state`` (ns; ``t`` when None), as the still track,
        judged over the ``SHADOW_FRAMES`` accepted readings after this frame's ``t``
        against the track that goes on: only ``SHADOW_QUIET_S`` or more after a hold
        ended (its state then the track at ``accel_psd``), and not over a still track
        already being judged. Called where a manoeuvre begins or the track restarts,
        before either starts a hold."""
        if t < self._quiet_ns or self._sh_on:
            return
        self._sh_on = True
        self._sh_x = x
        self._sh_v = v
        self._sh_p00 = p00
        self._sh_p01 = p01
        self._sh_p11 = p11
        self._sh_t_ns = t if t_state is None else t_state
        self._sh_llr = 0.0
        self._sh_left = SHADOW_FRAMES

    def _shadow_step(self, z: float, r: float, e2: float, sp: float, t: int) -> bool:
        """Take the accepted reading ``z`` (metres, variance ``r``, m^2, at ``t`` ns) into
        the still track, whose process noise is ``accel_psd``, after adding to the log
        likelihood ratio of the track over it (``e2``, ``sp``: the track's squared
        innovation and its predicted variance, m^2). On the last reading judged, return
        True when the still track is at least as likely, its state then the prediction
        before this reading, for the track to take and update."""
        dt = (t - self._sh_t_ns) * 1e-9
        self._sh_t_ns = t
        if dt > 0.0:
            x, p00, p01, p11 = _cv_predicted(
                self._sh_x, self._sh_v, self._sh_p00, self._sh_p01, self._sh_p11, self._qa_lo, dt
            )
        else:
            x = self._sh_x
            p00 = self._sh_p00
            p01 = self._sh_p01
            p11 = self._sh_p11
        es = z - x
        ss = p00 + r
        llr = self._sh_llr + 0.5 * (es * es / ss - e2 / sp + log(ss / sp))
        if llr > SHADOW_DROP_LLR:
            self._sh_on = False
            return False
        left = self._sh_left - 1
        if not left:
            self._sh_on = False
            if llr <= 0.0:
                self._sh_x = x
                self._sh_p00 = p00
                self._sh_p01 = p01
                self._sh_p11 = p11
                return True
            return False
        self._sh_llr = llr
        self._sh_left = left
        self._sh_x, self._sh_v, self._sh_p00, self._sh_p01, self._sh_p11 = _cv_updated(
            x, self._sh_v, p00, p01, p11, es, ss, r
        )
        return False

    def _settle(self, t_ns: int, r_m2: float, dt_s: float) -> None:
        """Schedule the step of the published variance from P00 down to
        ``STILL_VAR_RATIO`` P00 after a hold that ended at ``t_ns`` on a reading of
        variance ``r_m2`` (m^2), ``dt_s`` seconds after the frame before it. Without a
        period (dt 0, a stamp out of order) nothing is scheduled and P00 stays the
        published variance, on the safe side, until the next hold ends; nor with no
        process noise, where P00 is the error."""
        if dt_s > 0.0 and self._qa_lo > 0.0:
            tau_s = sqrt(sqrt(r_m2 * dt_s / self._qa_lo))
            self._still_ns = t_ns + round(STILL_SETTLE_TAUS * tau_s * 1e9)
            self._quiet_ns = t_ns + _SHADOW_QUIET_NS

    def _predict(self, dt_s: float) -> None:
        """Move the state ``dt_s`` (> 0) seconds ahead without a reading."""
        self.x, self.p00, self.p01, self.p11 = _cv_predicted(
            self.x, self.v, self.p00, self.p01, self.p11, self.qa, dt_s
        )

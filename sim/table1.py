"""Table I of the paper (seed 000, section IV.D, "Extended summary of simulation results").

How this works: each row of Table I is a slice of the paper's full factorial sweep
(section III: lux 0-70,000, R 0.1-0.9, theta 0-85 deg). The paper does not say which
cells each row averages, so every row here names the lux, R and theta intervals we
assume for it; ``lunad.sim.sweep`` pools the readings of every grid cell inside those
intervals. Intervals are closed unless marked open. The last row ("worst case") is
one-sided in the paper (">9.0" cm, ">35" %), so it is a lower bound, not a target.
"""

from __future__ import annotations

from dataclasses import dataclass

LUX_MAX = 70_000.0  # section III.1: illumination 0-70,000 lux
R_MIN, R_MAX = 0.1, 0.9  # section III.1: reflectivity 0.1-0.9
THETA_MAX_DEG = 85.0  # section III.1: incidence angle 0-85 deg

_EPS = 1e-9


@dataclass(frozen=True, slots=True)
class Interval:
    """A closed or half-open interval of one sweep variable (lux, R or degrees)."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, x: float) -> bool:
        """True when ``x`` lies in the interval (with a 1e-9 tolerance at the ends)."""
        above = x > self.lo + _EPS if self.lo_open else x >= self.lo - _EPS
        below = x < self.hi - _EPS if self.hi_open else x <= self.hi + _EPS
        return above and below

    def label(self) -> str:
        """Interval in mathematical notation, e.g. ``[0, 5000)``."""
        left = "(" if self.lo_open else "["
        right = ")" if self.hi_open else "]"
        return f"{left}{self.lo:g}, {self.hi:g}{right}"


ALL_LUX = Interval(0.0, LUX_MAX)
ALL_R = Interval(R_MIN, R_MAX)
ALL_THETA = Interval(0.0, THETA_MAX_DEG)


@dataclass(frozen=True, slots=True)
class Table1Row:
    """One row of Table I with the slice of the sweep we assume it summarises.

    Attributes:
        group: the Table I block ("illumination", "reflectivity", "angle", "combined").
        condition: the row label as printed in the paper.
        lux: assumed illuminance interval, lux.
        reflectivity: assumed reflectivity interval (a single value for R rows).
        theta_deg: assumed incidence-angle interval, degrees.
        mean_error_cm: the paper's mean absolute error, cm.
        failure_rate_pct: the paper's failure (dropout) rate, percent.
        lower_bound: True when the paper gives only ">" values (worst-case row).
    """

    group: str
    condition: str
    lux: Interval
    reflectivity: Interval
    theta_deg: Interval
    mean_error_cm: float
    failure_rate_pct: float
    lower_bound: bool = False


def _r(value: float) -> Interval:
    return Interval(value, value)


TABLE1_ROWS: tuple[Table1Row, ...] = (
    Table1Row(
        "illumination",
        "0-5000 lux (low)",
        Interval(0, 5000, hi_open=True),
        ALL_R,
        ALL_THETA,
        1.5,
        0.0,
    ),
    Table1Row(
        "illumination",
        "5000-20000 lux (moderate)",
        Interval(5000, 20000, hi_open=True),
        ALL_R,
        ALL_THETA,
        3.2,
        5.0,
    ),
    # ">20000 (high)" read as 20-50 klux so that it does not overlap ">50000 (extreme)".
    Table1Row(
        "illumination", ">20000 lux (high)", Interval(20000, 50000), ALL_R, ALL_THETA, 5.8, 12.0
    ),
    Table1Row(
        "illumination",
        ">50000 lux (extreme)",
        Interval(50000, LUX_MAX, lo_open=True),
        ALL_R,
        ALL_THETA,
        6.9,
        21.0,
    ),
    Table1Row("reflectivity", "R 0.1 (black matte)", ALL_LUX, _r(0.1), ALL_THETA, 6.5, 18.0),
    Table1Row("reflectivity", "R 0.3 (dark gray)", ALL_LUX, _r(0.3), ALL_THETA, 4.8, 13.0),
    Table1Row("reflectivity", "R 0.5 (neutral)", ALL_LUX, _r(0.5), ALL_THETA, 2.5, 5.0),
    Table1Row("reflectivity", "R 0.7 (light gray)", ALL_LUX, _r(0.7), ALL_THETA, 1.6, 2.0),
    Table1Row("reflectivity", "R 0.9 (white matte)", ALL_LUX, _r(0.9), ALL_THETA, 1.2, 1.0),
    Table1Row(
        "angle", "0-30 deg (near normal)", ALL_LUX, ALL_R, Interval(0, 30, hi_open=True), 1.8, 2.0
    ),
    Table1Row(
        "angle", "30-60 deg (moderate)", ALL_LUX, ALL_R, Interval(30, 60, hi_open=True), 4.1, 10.0
    ),
    Table1Row("angle", "60-75 deg (steep)", ALL_LUX, ALL_R, Interval(60, 75), 7.3, 25.0),
    Table1Row(
        "angle",
        ">75 deg (grazing)",
        ALL_LUX,
        ALL_R,
        Interval(75, THETA_MAX_DEG, lo_open=True),
        8.1,
        31.0,
    ),
    Table1Row(
        "combined",
        "L>50000, R=0.1, theta>75 (worst)",
        Interval(50000, LUX_MAX, lo_open=True),
        _r(0.1),
        Interval(75, THETA_MAX_DEG, lo_open=True),
        9.0,
        35.0,
        lower_bound=True,
    ),
)
"""Table I, seed 000 section IV.D, in the paper's order."""

FIT_ROWS: tuple[Table1Row, ...] = tuple(r for r in TABLE1_ROWS if not r.lower_bound)
"""The 13 two-sided rows: the targets of the calibrated fit and of the tolerance."""

WORST_CASE_ROW: Table1Row = TABLE1_ROWS[-1]


@dataclass(frozen=True, slots=True)
class TextTrend:
    """A trend the paper's text states for Fig. 2 or Fig. 3, as a bound over a stretch of x.

    The figures themselves are not in the text we have, only their descriptions, so
    ``lunad sweep --plot`` draws these bounds next to the model's curves. The text
    does not say which cells a sentence pools; ``targets`` names the curves it speaks of.

    Attributes:
        figure: 2 (x = illuminance, lux) or 3 (x = incidence angle, degrees).
        quantity: "error" (mean absolute error, cm) or "failure" (failure rate, percent).
        x_lo: start of the stretch of the x axis the sentence covers (lux or degrees).
        x_hi: its end (equal to ``x_lo`` for a single point).
        bound: the value the text gives, cm or percent.
        above: True for "over", "exceeding" (the curve lies above), False for "below".
        targets: the curves the sentence is about, e.g. "R 0.9".
        source: where the paper says it (section or abstract).
    """

    figure: int
    quantity: str
    x_lo: float
    x_hi: float
    bound: float
    above: bool
    targets: str
    source: str

    def label(self) -> str:
        """Short annotation, e.g. ``R 0.9 < 1 cm (IV.A)``."""
        unit = "cm" if self.quantity == "error" else "%"
        return f"{self.targets} {'>' if self.above else '<'} {self.bound:g} {unit} ({self.source})"


TEXT_TRENDS: tuple[TextTrend, ...] = (
    # IV.A: "highly reflective targets (R = 0.9) ... up to 70,000 lux, maintaining measurement
    # accuracy"; "reflective targets maintain sub-centimeter accuracy across most of the
    # illumination range".
    TextTrend(2, "error", 0.0, LUX_MAX, 1.0, False, "R 0.9", "IV.A"),
    # Abstract: "at high illumination levels (over 20,000 lux), the mean distance error
    # increases from below 2 cm to over 6 cm, with dropout rates exceeding 15% for
    # low-reflective surfaces" (which R the error is for is not said).
    TextTrend(2, "error", 0.0, 20000.0, 2.0, False, "R unstated", "abstract"),
    TextTrend(2, "error", 20000.0, LUX_MAX, 6.0, True, "R unstated", "abstract"),
    TextTrend(2, "failure", 20000.0, LUX_MAX, 15.0, True, "R 0.1", "abstract"),
    # IV.C: "to maintain sub-centimeter accuracy, the incidence angle should be kept below
    # 45°"; "the error increases rapidly, reaching over 6 cm at 75°".
    TextTrend(3, "error", 0.0, 45.0, 1.0, False, "R unstated", "IV.C"),
    TextTrend(3, "error", 75.0, 75.0, 6.0, True, "all R", "IV.C"),
    # Abstract: "For reflectivity values below 0.3 and angles above 60°, error rates exceeded
    # 7 cm and dropouts surpassed 20%" (R 0.1 is the plotted curve below 0.3).
    TextTrend(3, "error", 60.0, THETA_MAX_DEG, 7.0, True, "R 0.1", "abstract"),
    TextTrend(3, "failure", 60.0, THETA_MAX_DEG, 20.0, True, "R 0.1", "abstract"),
)
"""The figure descriptions of seed 000 (abstract, IV.A, IV.C) that carry a number."""

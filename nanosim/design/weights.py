"""H-infinity mixed-sensitivity weights (paper Sec. 4.2, Fig. 11b).

Each weight is a SISO transfer function ``(num(s) / den(s)) ** power`` in the
Laplace variable ``s`` [rad/s], placed on the diagonal of a 3x3 (or n x n)
matrix. The paper's weights (DOI 10.1115/1.2936861, Sec. 4.2, and
``shared/reference/paper_targets.json`` section ``hinf``) are::

    Wp(s) = (0.6667 s + 314.2) / (s + 0.03142)        on S   (sensor V / sensor V)
    Wt(s) = ((s + 314.2) / (0.001 s + 628.3)) ** 2     on T   (sensor V / sensor V)
    Wu    = 0.15                                        on KS  (1 / (controller V / sensor V))

``1/|Wp|`` is the bound on sigma(S): 1e-4 (-80 dB) at DC, 1.5 (+3.5 dB) at high
frequency, crossing 0 dB near 50 Hz. ``1/|Wt|`` bounds sigma(T): +12 dB at low
frequency, 0 dB near 100 Hz, -120 dB at high frequency, falling 40 dB/decade.

Weights must have all poles strictly in the open left half plane: a weight pole
on the imaginary axis (an integrator ``1/s`` or an undamped ``1/(s^2 + w^2)``)
makes the weighted output undetectable from the measurement and the standard
Doyle-Glover H-infinity solution (slycot ``sb10ad``) does not exist.
:meth:`Weights.check` raises ``ValueError`` naming the offending weight.
"""
from __future__ import annotations

import json
import os
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser from PyPI
    import tomli as tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

__all__ = ["WeightSpec", "Weights", "PAPER_WEIGHTS", "paper_weights", "WEIGHT_NAMES"]

WEIGHT_NAMES = ("Wp", "Wt", "Wu")
_WEIGHT_ROLE = {"Wp": "S (performance)", "Wt": "T (roll-off / noise)", "Wu": "KS (control effort)"}
# A pole with |Re p| <= _AXIS_RTOL * max(1, |p|) counts as "on the imaginary axis".
_AXIS_RTOL = 1e-9


def _coeffs(name: str, what: str, value) -> tuple[float, ...]:
    try:
        if np.iscomplexobj(value):
            raise TypeError("complex")
        arr = np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{name}.{what}: expected a list of numbers, got {value!r}") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name}.{what}: expected a non-empty 1-D list of polynomial coefficients, "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}.{what}: coefficients must be finite, got {arr.tolist()}")
    nz = np.flatnonzero(arr)
    if nz.size == 0:
        if what == "den":
            raise ValueError(f"{name}.den: denominator is identically zero")
        return (0.0,)
    return tuple(float(c) for c in arr[nz[0]:])   # drop leading zeros


@dataclass(frozen=True)
class WeightSpec:
    """One SISO weight ``W(s) = (num(s)/den(s)) ** power``.

    Parameters
    ----------
    num, den : tuple of float
        Polynomial coefficients in descending powers of ``s`` [rad/s]
        (``numpy.polyval`` order). Leading zeros are dropped.
    power : int, default 1
        Integer power >= 1 applied to the ratio (the paper's Wt uses 2).
    name : str, default "W"
        Label used in error messages (``"Wp"``, ``"Wt"``, ``"Wu"``).
    """

    num: tuple[float, ...]
    den: tuple[float, ...] = (1.0,)
    power: int = 1
    name: str = field(default="W", compare=False)

    def __post_init__(self):
        object.__setattr__(self, "num", _coeffs(self.name, "num", self.num))
        object.__setattr__(self, "den", _coeffs(self.name, "den", self.den))
        p = self.power
        try:
            whole = not isinstance(p, bool) and float(p).is_integer() and int(p) >= 1
        except (TypeError, ValueError, OverflowError):
            whole = False
        if not whole:
            raise ValueError(f"{self.name}.power: expected an integer >= 1, got {p!r}")
        object.__setattr__(self, "power", int(p))

    # --- construction -------------------------------------------------------------
    @classmethod
    def from_value(cls, value: Any, name: str = "W") -> "WeightSpec":
        """Build from a number (static weight), a mapping with ``num``/``den``/
        ``power`` keys, or another :class:`WeightSpec` (renamed to ``name``).
        """
        if isinstance(value, WeightSpec):
            return cls(value.num, value.den, value.power, name=name)
        if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
            return cls((float(value),), (1.0,), 1, name=name)
        if isinstance(value, Mapping):
            unknown = set(value) - {"num", "den", "power"}
            if unknown:
                raise ValueError(f"{name}: unknown fields {sorted(unknown)}; expected num, den, power")
            if "num" not in value:
                raise ValueError(f"{name}: missing field 'num' (numerator coefficients, descending powers of s)")
            return cls(value["num"], value.get("den", (1.0,)), value.get("power", 1), name=name)
        raise ValueError(f"{name}: expected a number or a table with num/den/power, got {type(value).__name__}")

    def to_dict(self) -> dict:
        """``{"num": [...], "den": [...], "power": p}`` (JSON/TOML friendly)."""
        return {"num": list(self.num), "den": list(self.den), "power": self.power}

    # --- properties ----------------------------------------------------------------
    @property
    def is_static(self) -> bool:
        """True when the weight is a constant gain."""
        return len(self.num) == 1 and len(self.den) == 1

    @property
    def order(self) -> int:
        """Number of states of one SISO realization (``power * deg(den)``)."""
        return self.power * (len(self.den) - 1)

    def poles(self) -> np.ndarray:
        """Poles [rad/s] (each repeated ``power`` times)."""
        return np.tile(np.roots(self.den), self.power) if len(self.den) > 1 else np.zeros(0, complex)

    def dc_gain(self) -> float:
        """W(0); ``inf`` for a pole at s = 0."""
        d = self.den[-1]
        return float("inf") if d == 0 else float((self.num[-1] / d) ** self.power)

    def hf_gain(self) -> float:
        """lim_{s->inf} W(s) (0 for strictly proper weights)."""
        if len(self.num) < len(self.den):
            return 0.0
        return float((self.num[0] / self.den[0]) ** self.power)

    def freqresp(self, freq_hz) -> np.ndarray:
        """Complex W(j 2 pi f) for ``freq_hz`` [Hz]; same shape as ``freq_hz``."""
        s = 2j * np.pi * np.asarray(freq_hz, dtype=float)
        return (np.polyval(self.num, s) / np.polyval(self.den, s)) ** self.power

    # --- checks ----------------------------------------------------------------------
    def check(self) -> None:
        """Raise ``ValueError`` if this weight cannot be used in H-infinity synthesis.

        Rejects improper weights (deg num > deg den), an identically zero weight,
        and poles on the imaginary axis (integrators, undamped resonances) or in
        the right half plane; the message names the weight.
        """
        nm = self.name
        role = _WEIGHT_ROLE.get(nm, "its closed-loop map")
        if len(self.num) > len(self.den):
            raise ValueError(f"{nm} (weight on {role}) is improper: numerator degree {len(self.num) - 1} > "
                             f"denominator degree {len(self.den) - 1}; add fast poles to make it proper")
        if self.num == (0.0,):
            raise ValueError(f"{nm} (weight on {role}) is identically zero")
        for p in np.unique(np.round(self.poles(), 12)):
            on_axis = abs(p.real) <= _AXIS_RTOL * max(1.0, abs(p))
            if on_axis:
                what = ("an integrator 1/s" if abs(p) <= _AXIS_RTOL
                        else f"an undamped mode at {abs(p.imag) / (2 * np.pi):.4g} Hz")
                raise ValueError(
                    f"{nm} (weight on {role}) has a pole on the imaginary axis at s = {p:.4g} rad/s ({what}). "
                    f"The H-infinity synthesis needs weights with all poles strictly in the left half plane: "
                    f"such a weight state is not detectable from the measured error, so the Doyle-Glover "
                    f"Riccati solution does not exist. Move the pole slightly left, e.g. 1/s -> 1/(s + 1e-4*wb) "
                    f"as in the paper's Wp = (0.6667 s + 314.2)/(s + 0.03142).")
            if p.real > 0:
                raise ValueError(f"{nm} (weight on {role}) is unstable: pole at s = {p:.4g} rad/s in the right "
                                 f"half plane; weights must be stable")

    # --- realizations --------------------------------------------------------------------
    def tf(self):
        """SISO ``control.TransferFunction`` of the weight."""
        import control as ct
        return ct.tf(list(self.num), list(self.den)) ** self.power

    def ss(self):
        """SISO ``control.StateSpace``: ``power`` copies of ``num/den`` in series
        (better conditioned than expanding the power into one polynomial).
        """
        import control as ct
        base = ct.ss(ct.tf(list(self.num), list(self.den)))
        out = base
        for _ in range(self.power - 1):
            out = ct.series(out, base)
        return out

    def ss_diag(self, n: int):
        """``n x n`` diagonal ``control.StateSpace`` ``W(s) I_n``."""
        import control as ct
        w = self.ss()
        if w.nstates == 0:
            return ct.ss(np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), float(w.D[0, 0]) * np.eye(n))
        return ct.append(*([w] * n))


def _paper(name, num, den, power=1):
    return WeightSpec(tuple(num), tuple(den), power, name=name)


@dataclass(frozen=True)
class Weights:
    """The three mixed-sensitivity weights, each applied as ``W(s) * I``.

    Defaults are the paper's (Sec. 4.2): ``Wp = (0.6667 s + 314.2)/(s + 0.03142)``,
    ``Wt = ((s + 314.2)/(0.001 s + 628.3))**2``, ``Wu = 0.15``.

    Parameters
    ----------
    Wp : WeightSpec, number, mapping or None
        Weight on the sensitivity S (error / reference) [dimensionless].
    Wt : WeightSpec, number, mapping or None
        Weight on the complementary sensitivity T (output / reference) [dimensionless].
    Wu : WeightSpec, number, mapping or None
        Weight on KS (controller volts / sensor volts) [sensor V / controller V].

    ``None`` leaves that closed-loop map unweighted (e.g. an S/KS design without
    Wt, as in Skogestad & Postlethwaite Example 2.11); at least one is required.
    """

    Wp: WeightSpec = _paper("Wp", (0.6667, 314.2), (1.0, 0.03142))
    Wt: WeightSpec = _paper("Wt", (1.0, 314.2), (0.001, 628.3), 2)
    Wu: WeightSpec = _paper("Wu", (0.15,), (1.0,))

    def __post_init__(self):
        for nm in WEIGHT_NAMES:
            val = getattr(self, nm)
            object.__setattr__(self, nm, None if val is None else WeightSpec.from_value(val, nm))
        if all(getattr(self, nm) is None for nm in WEIGHT_NAMES):
            raise ValueError("weights: at least one of Wp, Wt, Wu must be given")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Weights":
        """Build from ``{"Wp": {...}, "Wt": {...}, "Wu": 0.15}``.

        Each entry is a number, a table ``{num, den, power}``, or ``null`` /
        ``false`` / ``"none"`` for an unweighted map (TOML has no null). A mapping with a
        ``"hinf"`` sub-table (``paper_targets.json``) is accepted; other keys
        (``gamma``, ...) are ignored. All three keys are required.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"weights: expected a mapping, got {type(data).__name__}")
        if not any(k in data for k in WEIGHT_NAMES) and isinstance(data.get("hinf"), Mapping):
            data = data["hinf"]
        missing = [k for k in WEIGHT_NAMES if k not in data]
        if missing:
            near = [k for k in data if isinstance(k, str) and k.lower() in {"wp", "wt", "wu"} and k not in WEIGHT_NAMES]
            hint = f" (keys are case sensitive; found {near})" if near else ""
            raise ValueError(f"weights: missing {missing}; expected keys Wp, Wt, Wu (null/false/'none' to omit "
                             f"one){hint}")

        def absent(v):
            return v is None or v is False or (isinstance(v, str) and v.strip().lower() == "none")
        return cls(**{k: None if absent(data[k]) else WeightSpec.from_value(data[k], k) for k in WEIGHT_NAMES})

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> "Weights":
        """Load from a ``.json`` or ``.toml`` file (format of :meth:`from_dict`)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: weights file not found")
        suffix = path.suffix.lower()
        try:
            if suffix == ".toml":
                data = tomllib.loads(path.read_text())
            elif suffix == ".json":
                data = json.loads(path.read_text())
            else:
                raise ValueError(f"{path}: weights file must end in .json or .toml")
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"{path}: cannot parse weights ({exc})") from None
        return cls.from_dict(data)

    @classmethod
    def coerce(cls, value) -> "Weights":
        """``None`` -> paper weights; Weights, mapping or file path accepted."""
        if value is None:
            return cls()
        if isinstance(value, Weights):
            return value
        if isinstance(value, Mapping):
            return cls.from_dict(value)
        if isinstance(value, (str, os.PathLike)):
            return cls.from_file(value)
        raise ValueError("weights: expected None, Weights, a mapping or a .json/.toml path, "
                         f"got {type(value).__name__}")

    def to_dict(self) -> dict:
        """``{"Wp": {...}, "Wt": {...}, "Wu": {...}}`` with num/den/power lists
        (``None`` for an omitted weight).
        """
        return {k: None if getattr(self, k) is None else getattr(self, k).to_dict() for k in WEIGHT_NAMES}

    def check(self) -> None:
        """Raise ``ValueError`` naming the first weight unusable for synthesis."""
        for k in WEIGHT_NAMES:
            if getattr(self, k) is not None:
                getattr(self, k).check()

    def statespace(self, ny: int, nu: int):
        """Diagonal state-space weights ``(Wp I_ny, Wu I_nu, Wt I_ny)`` in the
        argument order of ``control.augw(G, w1, w2, w3)``; ``None`` for omitted ones.
        """
        return (None if self.Wp is None else self.Wp.ss_diag(ny),
                None if self.Wu is None else self.Wu.ss_diag(nu),
                None if self.Wt is None else self.Wt.ss_diag(ny))

    def order_for(self, ny: int, nu: int) -> int:
        """Total weight states for an ``ny x nu`` plant (the controller order is
        plant order + this). Paper: 3*1 + 3*0 + 3*2 = 9.
        """
        o = {k: 0 if getattr(self, k) is None else getattr(self, k).order for k in WEIGHT_NAMES}
        return ny * (o["Wp"] + o["Wt"]) + nu * o["Wu"]


PAPER_WEIGHTS = Weights()


def paper_weights() -> Weights:
    """The paper's weights (Sec. 4.2); same as ``Weights()``."""
    return Weights()

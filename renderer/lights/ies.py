"""IES LM-63 photometric profiles: a parser and a bilinear (theta, phi) lookup (no pxr).

**Formats.** LM-63-1986 (no first line), LM-63-1991 (``IESNA91``), LM-63-1995
(``IESNA:LM-63-1995``), LM-63-2002 (``IESNA:LM-63-2002``) and LM-63-2019 (``IES:LM-63-2019``).
Keyword lines (``[TEST] ...``) up to the ``TILT=`` line are skipped. After it the file is a
stream of numbers separated by blanks, commas or line breaks:

    lamps  lumens/lamp  candela-multiplier  #vertical  #horizontal  photometric-type
    units  width  length  height
    ballast-factor  <second factor>  input-watts
    vertical angles (#vertical)   horizontal angles (#horizontal)
    candela values: #horizontal rows of #vertical values (one row per horizontal angle)

Candela values are multiplied by ``candela-multiplier * ballast-factor``; the second factor is
the "ballast-lamp photometric factor" only in LM-63-1995 (and older) files, where it is
multiplied in too; in LM-63-2002 it is "future use" and in LM-63-2019 the "file generation
type" (1.00001 ...), so it is ignored there. (Cycles, and hdEmbree which uses its parser,
multiply it in every version.) Lamp count, lumens, units, luminous-opening size and watts are
read and ignored: the light's own UsdLux geometry emits.

**TILT.** ``TILT=NONE`` is the common case. ``TILT=INCLUDE`` blocks (lamp-to-luminaire
geometry, tilt angles and multiplying factors) are parsed and ignored: they describe how the
lamp output changes when the luminaire is mounted tilted, and illum, like Cycles and hdEmbree,
renders the profile as measured. ``TILT=<file>`` (an external tilt file) is an error.

**Photometric type.** Only type C (1; vertical angle 0 = nadir, the luminaire's axis,
horizontal angle about that axis) is supported. Type B (2) and type A (3) use a horizontal
polar axis (floodlights, automotive) and are rejected with an error rather than silently
transposed as Cycles does.

**Symmetry.** Vertical angles must increase within [0, 180] degrees (typically 0..90, 90..180
or 0..180). Horizontal angles must increase and start at 0 with the last one 0 (rotationally
symmetric), 90 (symmetric in each quadrant), 180 (symmetric about the 0-180 plane) or 360
(full); a 0-based table that stops one step short of 360 gets the 360 entry copied from 0 (a
common slip that Cycles also repairs); a table from 90 to 270 is symmetric about the 90-270
plane. Everything is expanded to a periodic table over [0, 360] degrees.

**Lookup.** ``IesProfile.eval(theta, phi)`` interpolates bilinearly in (theta, phi) (as
hdEmbree's PxrIESFile::eval and Cycles do); theta outside the table's vertical range gives 0
(e.g. the upper hemisphere of a 0..90 downlight).

**Power** (for ``shaping:ies:normalize``): the exact integral of that bilinear interpolant over
the sphere, divided by 4 pi, or by 2 pi when the vertical angles span no more than
90 degrees + 0.1 rad (a hemispherical profile). That is hdEmbree's definition (pxrIES.cpp
``pxr_extra_process``, "matches Karma & RIS"), computed exactly instead of by its midpoint
rule: the mean intensity over the (hemi)sphere, so a normalized isotropic profile is 1.

Every error is an ``IesError`` naming the file and the line.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from renderer.assets import asset_bytes
from renderer.errors import StageError

__all__ = ["IesError", "IesProfile", "load_ies", "parse_ies"]

_MAX_ANGLES = 100_000
# hdEmbree's test for "the profile covers more than a hemisphere" (pxrIES.cpp).
_HEMISPHERE_SPAN = math.pi / 2.0 + 0.1
_ANGLE_TOL = 1e-4  # degrees: angles this close count as equal (as Cycles' angle_close)


class IesError(StageError):
    """A malformed or unsupported IES file; the message names the file and the line."""


@dataclass(frozen=True)
class IesProfile:
    """A type C photometric profile, expanded to the full sphere of horizontal angles.

    file: the path it was read from; version: 'LM-63-1986' ... 'LM-63-2019'.
    theta: (V,) vertical angles in radians, increasing, within [0, pi] (0 = the light's axis).
    phi: (H,) horizontal angles in radians, increasing, periodic: phi[0] <= 0 and
        phi[-1] >= 2 pi, so any phi in [0, 2 pi) falls inside one interval.
    candela: (H, V) intensities (cd, multipliers applied), >= 0.
    """

    file: str
    version: str
    theta: np.ndarray
    phi: np.ndarray
    candela: np.ndarray

    # ------------------------------------------------------------------------------
    def eval(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Bilinear intensity (n,) at vertical angles theta (n,) and horizontal phi (n,), radians.

        theta outside [theta[0], theta[-1]] gives 0; phi is taken modulo 2 pi.
        """
        theta = np.asarray(theta, dtype=np.float64)
        phi = np.mod(np.asarray(phi, dtype=np.float64), 2.0 * math.pi)
        V, H, C = self.theta, self.phi, self.candela
        inside = (theta >= V[0]) & (theta <= V[-1])
        j = np.clip(np.searchsorted(V, theta, side="right") - 1, 0, V.size - 2)
        s = np.clip((theta - V[j]) / (V[j + 1] - V[j]), 0.0, 1.0)
        i = np.clip(np.searchsorted(H, phi, side="right") - 1, 0, H.size - 2)
        t = np.clip((phi - H[i]) / (H[i + 1] - H[i]), 0.0, 1.0)
        a = C[i, j] * (1.0 - s) + C[i, j + 1] * s
        b = C[i + 1, j] * (1.0 - s) + C[i + 1, j + 1] * s
        return np.where(inside, a * (1.0 - t) + b * t, 0.0)

    def integral(self) -> float:
        """Exact integral of the bilinear interpolant over the sphere, cd * sr (= lumens)."""
        V, H, C = self.theta, self.phi, self.candela
        # Clip the periodic table to one period [0, 2 pi]: the interpolant is linear between
        # knots, so splitting an interval at 0 or 2 pi keeps it exact.
        knots = np.unique(np.concatenate([np.clip(H, 0.0, 2.0 * math.pi), [0.0, 2.0 * math.pi]]))
        knots = knots[(knots >= 0.0) & (knots <= 2.0 * math.pi)]
        rows = np.stack([self._row_at(p) for p in knots])  # (K, V): intensity along each knot
        dphi = np.diff(knots)
        # Trapezoid in phi is exact for a piecewise-linear function with these knots.
        g = 0.5 * ((rows[:-1] + rows[1:]) * dphi[:, None]).sum(axis=0)  # (V,) integral over phi
        t0, t1 = V[:-1], V[1:]
        h = t1 - t0
        # ∫ (g0 + (g1 - g0)(θ - θ0)/h) sin θ dθ over [θ0, θ1], in closed form.
        m0 = np.cos(t0) - np.cos(t1)
        m1 = (np.sin(t1) - np.sin(t0) - h * np.cos(t1)) / h
        return float((g[:-1] * m0 + (g[1:] - g[:-1]) * m1).sum())

    def _row_at(self, p: float) -> np.ndarray:
        """(V,) intensities at horizontal angle p (linear between the table's rows)."""
        H, C = self.phi, self.candela
        i = int(np.clip(np.searchsorted(H, p, side="right") - 1, 0, H.size - 2))
        t = min(max((p - H[i]) / (H[i + 1] - H[i]), 0.0), 1.0)
        return C[i] * (1.0 - t) + C[i + 1] * t

    def power(self) -> float:
        """hdEmbree's profile power: the mean intensity over the sphere (over the hemisphere
        for profiles spanning <= 90 degrees + 0.1 rad of vertical angle), in cd."""
        span = float(self.theta[-1] - self.theta[0])
        return self.integral() / ((4.0 if span > _HEMISPHERE_SPAN else 2.0) * math.pi)

    def theta_support(self) -> float:
        """An upper bound (radians) of the vertical angles where the intensity can be > 0,
        or -1 when the profile is zero everywhere."""
        nz = np.nonzero(np.any(self.candela > 0.0, axis=0))[0]
        if nz.size == 0:
            return -1.0
        j = int(nz[-1])
        return float(self.theta[min(j + 1, self.theta.size - 1)])

    def knots_theta(self) -> np.ndarray:
        return self.theta

    def knots_phi(self) -> np.ndarray:
        """The horizontal knots within [0, 2 pi] (plus both ends)."""
        k = self.phi[(self.phi > 0.0) & (self.phi < 2.0 * math.pi)]
        return np.concatenate([[0.0], k, [2.0 * math.pi]])


# ----------------------------------------------------------------------------------------
# Parsing
# ----------------------------------------------------------------------------------------
_VERSIONS = (
    (re.compile(r"^IES:LM-63-2019"), "LM-63-2019"),
    (re.compile(r"^IESNA:LM-63-2002"), "LM-63-2002"),
    (re.compile(r"^IESNA:LM-63-1995"), "LM-63-1995"),
    (re.compile(r"^IESNA91"), "LM-63-1991"),
)


class _Tokens:
    """Numbers after the TILT line, each with its 1-based line number."""

    def __init__(self, file: str, lines: list[str], first: int):
        self.file = file
        self.items: list[tuple[str, int]] = []
        for k in range(first, len(lines)):
            for tok in lines[k].replace(",", " ").split():
                self.items.append((tok, k + 1))
        self.pos = 0
        self.last_line = len(lines)

    def error(self, message: str, line: int | None = None) -> IesError:
        return IesError(f"line {line if line is not None else self.last_line}: {message}", file=self.file)

    def number(self, what: str) -> tuple[float, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of file: expected {what}")
        tok, line = self.items[self.pos]
        self.pos += 1
        try:
            v = float(tok)
        except ValueError:
            raise self.error(f"expected {what}, found '{tok}'", line) from None
        if not math.isfinite(v):
            raise self.error(f"{what} is '{tok}' (must be finite)", line)
        return v, line

    def integer(self, what: str, lo: int, hi: int) -> tuple[int, int]:
        v, line = self.number(what)
        if v != int(v) or not lo <= v <= hi:
            raise self.error(f"{what} is {v:g} (must be an integer in [{lo}, {hi}])", line)
        return int(v), line

    def array(self, n: int, what: str) -> tuple[np.ndarray, list[int]]:
        if self.pos + n > len(self.items):
            have = len(self.items) - self.pos
            raise self.error(f"unexpected end of file: expected {n} {what}, found {have}")
        out = np.empty(n)
        lines = []
        for k in range(n):
            out[k], line = self.number(what)
            lines.append(line)
        return out, lines


def load_ies(path: str, data: bytes | None = None) -> IesProfile:
    """Read and parse an IES file (``data``: its bytes when it is not a file on disk, e.g. inside
    a .usdz package; renderer/assets.py); IesError (naming the file) when unreadable or malformed."""
    try:
        data = asset_bytes(path, data)
    except OSError as exc:
        raise IesError(f"cannot read IES file: {exc.strerror or exc}", file=str(path)) from None
    # IES files are ASCII; keyword text in the wild is often Latin-1.
    return parse_ies(data.decode("latin-1"), str(path))


def parse_ies(text: str, file: str = "<string>") -> IesProfile:
    """Parse the text of an IES LM-63 file (see the module docstring)."""
    lines = text.lstrip("\ufeff\xef\xbb\xbf").splitlines()
    version = "LM-63-1986"
    if lines:
        for pattern, name in _VERSIONS:
            if pattern.match(lines[0].strip()):
                version = name
                break
    tilt_at = next((k for k, ln in enumerate(lines) if ln.strip().upper().startswith("TILT")), None)
    if tilt_at is None:
        raise IesError(f"line {max(len(lines), 1)}: no 'TILT=' line found (not an IES LM-63 file?)", file=file)
    tilt_line = lines[tilt_at].strip()
    tilt = tilt_line.split("=", 1)[1].strip() if "=" in tilt_line else ""
    tok = _Tokens(file, lines, tilt_at + 1)
    if tilt.upper() == "INCLUDE":
        tok.integer("lamp-to-luminaire geometry", 1, 3)
        n_tilt, _ = tok.integer("number of tilt angles", 0, _MAX_ANGLES)
        tok.array(2 * n_tilt, "tilt angles and factors")
    elif tilt.upper() != "NONE":
        raise tok.error(f"TILT={tilt!r}: external tilt files are not supported (use TILT=NONE or "
                        f"TILT=INCLUDE)", tilt_at + 1)

    tok.integer("number of lamps", -(2**31), 2**31)
    tok.number("lumens per lamp")
    multiplier, line = tok.number("candela multiplier")
    if multiplier < 0.0:
        raise tok.error(f"candela multiplier is {multiplier:g} (must be >= 0)", line)
    n_v, _ = tok.integer("number of vertical angles", 2, _MAX_ANGLES)
    n_h, _ = tok.integer("number of horizontal angles", 1, _MAX_ANGLES)
    ptype, line = tok.integer("photometric type", 1, 3)
    if ptype != 1:
        raise tok.error(f"photometric type {'B' if ptype == 2 else 'A'} ({ptype}) is not supported "
                        f"(only type C, 1)", line)
    tok.integer("units type", 1, 2)
    for what in ("luminous width", "luminous length", "luminous height"):
        tok.number(what)
    ballast, line = tok.number("ballast factor")
    second, line2 = tok.number("ballast-lamp photometric factor / future use")
    tok.number("input watts")
    factor = multiplier * ballast
    if version in ("LM-63-1986", "LM-63-1991", "LM-63-1995"):
        factor *= second
    if factor < 0.0:
        raise tok.error(f"ballast factor is {ballast:g} (must be >= 0)", line)

    v_deg, v_lines = tok.array(n_v, "vertical angles")
    h_deg, h_lines = tok.array(n_h, "horizontal angles")
    cand, c_lines = tok.array(n_v * n_h, "candela values")
    bad = np.nonzero(np.diff(v_deg) <= 0.0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise tok.error(f"vertical angles must increase ({v_deg[k - 1]:g} then {v_deg[k]:g})", v_lines[k])
    if v_deg[0] < -_ANGLE_TOL or v_deg[-1] > 180.0 + _ANGLE_TOL:
        k = 0 if v_deg[0] < 0 else n_v - 1
        raise tok.error(f"vertical angle {v_deg[k]:g} is outside [0, 180] (type C)", v_lines[k])
    bad = np.nonzero(np.diff(h_deg) <= 0.0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise tok.error(f"horizontal angles must increase ({h_deg[k - 1]:g} then {h_deg[k]:g})", h_lines[k])
    neg = np.nonzero(cand < 0.0)[0]
    if neg.size:
        k = int(neg[0])
        raise tok.error(f"candela value {cand[k]:g} is negative", c_lines[k])
    table = cand.reshape(n_h, n_v) * factor
    phi_deg, rows = _expand_horizontal(h_deg, table, tok, h_lines)
    phi = np.radians(phi_deg)
    # Periodic closure: one knot beyond each end, so every phi in [0, 2 pi) is bracketed.
    phi = np.concatenate([[phi[-2] - 2.0 * math.pi], phi, [phi[1] + 2.0 * math.pi]])
    rows = np.concatenate([rows[-2:-1], rows, rows[1:2]])
    return IesProfile(file=file, version=version, theta=np.radians(np.clip(v_deg, 0.0, 180.0)),
                      phi=phi, candela=np.ascontiguousarray(rows))


def _close(a: float, b: float) -> bool:
    return abs(a - b) < _ANGLE_TOL


def _expand_horizontal(h: np.ndarray, table: np.ndarray, tok: _Tokens, lines: list[int]):
    """Symmetry-expand horizontal angles (degrees) and rows to one full turn [0, 360]."""
    first, last = float(h[0]), float(h[-1])
    if _close(first, 0.0):
        h = h - first  # exactly 0
        if h.size == 1:
            return np.array([0.0, 360.0]), np.stack([table[0], table[0]])
        if _close(last, 90.0):
            # Symmetric in each quadrant: mirror to 0..180, then about the 0-180 plane.
            h = np.concatenate([h, 180.0 - h[-2::-1]])
            table = np.concatenate([table, table[-2::-1]])
            last = 180.0
        if _close(last, 180.0):
            h = np.concatenate([h, 360.0 - h[-2::-1]])
            table = np.concatenate([table, table[-2::-1]])
        elif not _close(h[-1], 360.0):
            gap = 360.0 - float(h[-1])
            if gap > 0.0 and (_close(gap, h[-1] - h[-2]) or _close(gap, h[1] - h[0])):
                h = np.concatenate([h, [360.0]])
                table = np.concatenate([table, table[:1]])
            else:
                raise tok.error(f"horizontal angles end at {last:g}: a type C table starting at 0 must end "
                                f"at 0, 90, 180 or 360", lines[-1])
        h[-1] = 360.0
        return h, table
    if _close(first, 90.0) and _close(last, 270.0):
        # Symmetric about the 90-270 plane: I(phi) = I(180 - phi).
        up = h <= 180.0 + _ANGLE_TOL
        lo = h >= 180.0 - _ANGLE_TOL
        a_h = (180.0 - h[up])[::-1]            # from the 90..180 half: 0..90
        a_t = table[up][::-1]
        c_h = (540.0 - h[lo])[::-1]            # from the 180..270 half: 270..360
        c_t = table[lo][::-1]
        hh = np.concatenate([a_h[:-1], h, c_h[1:]])
        tt = np.concatenate([a_t[:-1], table, c_t[1:]])
        if not (_close(hh[0], 0.0) and _close(hh[-1], 360.0)):
            raise tok.error("a type C table from 90 to 270 degrees must contain the 180 degree plane", lines[0])
        hh[0], hh[-1] = 0.0, 360.0
        return hh, tt
    raise tok.error(f"horizontal angles {first:g}..{last:g}: a type C table must start at 0 (or run "
                    f"from 90 to 270)", lines[0])


def describe(profile: IesProfile) -> str:
    return f"{os.path.basename(profile.file)} ({profile.version}, {profile.theta.size} x {profile.phi.size - 2})"

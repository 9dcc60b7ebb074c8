"""The sky of a geostationary satellite: Sun and Moon directions, eclipses by the Earth and Moon.

Everything comes from pyerfa (the IAU's SOFA routines, offline):

- **time**: a UTC epoch (ISO 8601) becomes TAI, so that ``t`` seconds after it
  are uniform; TT = TAI + 32.184 s; UT1 is taken equal to UTC (|UT1 − UTC| <
  0.9 s, i.e. < 0.004° of Earth rotation; no IERS download);
- **Sun**: ``erfa.epv00`` (the Earth's heliocentric and barycentric position,
  ~ 4 km), with annual aberration (``erfa.ab``): the apparent direction;
- **Moon**: ``erfa.moon98`` (Meeus' series, ~ 10″), geometric;
- **Earth rotation**: GCRS → terrestrial by the CIO chain, ``erfa.c2i06a``
  and the Earth rotation angle ``erfa.era00``; polar motion (< 0.5″) is left out.

The satellite sits on the equator at ``longitude_deg`` at the geostationary
radius; its orbital frame (see ``frames``) has z to nadir, x east (along the
velocity) and y south. Vectors returned are satellite-relative positions in
that frame, metres, so the Moon's 6° parallax and the Sun's 0.016° are in.

Shadows use the conical model with both bodies as discs (Montenbruck & Gill,
*Satellite Orbits*, §3.4.2): the sunlit fraction is 1 minus the share of the
Sun's disc the occulting disc covers, so the penumbra is graded. The Earth is
a sphere of its equatorial radius (oblateness and the atmosphere are left out:
they change the shadow's edge by some tens of km, seconds at GEO).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import erfa
import numpy as np

from rwlab.attitude.frames import EARTH_RADIUS, GEO_RADIUS
from rwlab.errors import ConfigError

__all__ = [
    "MOON_RADIUS",
    "SKY_COLUMNS",
    "SUN_RADIUS",
    "Epoch",
    "occulted_fraction",
    "parse_epoch",
    "sky_table",
    "sun_moon_orbital",
]

SUN_RADIUS = 6.957e8  # m, IAU 2015 nominal
MOON_RADIUS = 1.7374e6  # m
AU = erfa.DAU  # m
SUN_NODE_S = 60.0  # the Sun's and Moon's ephemerides are evaluated on this grid, interpolated
ROTATION_NODE_S = 3600.0  # the same for the precession-nutation matrix
SKY_COLUMNS = (
    "sun_x",
    "sun_y",
    "sun_z",
    "moon_x",
    "moon_y",
    "moon_z",
    "sunlit",
    "earth_lit",
    "moon_visible",
    "srp_scale",
)


@dataclass(frozen=True)
class Epoch:
    """A UTC instant as a two-part TAI Julian date (``tai1 + tai2`` days).

    Parameters
    ----------
    text : str
        The epoch as given (ISO 8601).
    tai1, tai2 : float
        The two parts of the TAI Julian date, days.
    """

    text: str
    tai1: float
    tai2: float

    def dates(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """TT and UT1 (= UTC) two-part Julian dates of the times ``t`` (s after the epoch)."""
        tai2 = self.tai2 + np.asarray(t, dtype=float) / 86400.0
        tt1, tt2 = erfa.taitt(self.tai1, tai2)
        ut1, ut2 = erfa.taiutc(self.tai1, tai2)
        return tt1, tt2, ut1, ut2


def parse_epoch(text: str) -> Epoch:
    """A UTC epoch from ISO 8601 (``2027-03-20T12:00:00Z``; no zone means UTC).

    Raises :class:`~rwlab.errors.ConfigError` when the text is not an ISO 8601
    date-time, or lies outside 1900–2100 (the ephemerides' range of validity).

    Parameters
    ----------
    text : str
        ISO 8601 date-time.

    Returns
    -------
    Epoch
    """
    try:
        when = datetime.fromisoformat(str(text).strip())
    except ValueError:
        raise ConfigError(
            f"epoch {text!r} is not an ISO 8601 date-time (e.g. 2027-03-20T12:00:00Z)"
        ) from None
    if when.tzinfo is not None:
        when = when.astimezone(UTC)
    if not 1900 <= when.year <= 2100:
        raise ConfigError(f"epoch {text!r}: the ephemerides cover 1900–2100")
    sec = when.second + when.microsecond * 1e-6
    u1, u2 = erfa.dtf2d("UTC", when.year, when.month, when.day, when.hour, when.minute, sec)
    tai1, tai2 = erfa.utctai(u1, u2)
    return Epoch(str(text), float(tai1), float(tai2))


def _interpolated(f, t: np.ndarray, node_s: float) -> np.ndarray:
    """f evaluated at the grid nodes around each t and interpolated linearly (f: s → (N, ...))."""
    k = np.floor(t / node_s)
    nodes = np.unique(np.concatenate([k, k + 1]))
    values = f(nodes * node_s)
    i = np.clip(np.searchsorted(nodes, k), 0, nodes.size - 2)
    w = ((t - nodes[i] * node_s) / node_s).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1 - w) * values[i] + w * values[i + 1]


def _sun_gcrs(epoch: Epoch, t: np.ndarray) -> np.ndarray:
    """Apparent geocentric Sun (aberration included), GCRS, metres, (N, 3)."""
    tt1, tt2, _, _ = epoch.dates(t)
    pvh, pvb = erfa.epv00(tt1, tt2)
    sun = -pvh["p"]  # the Sun seen from the Earth's centre, au (pyerfa's pv records)
    dist = np.linalg.norm(sun, axis=-1)
    v = pvb["v"] / erfa.DC  # the Earth's barycentric velocity / c
    bm1 = np.sqrt(1 - np.sum(v * v, axis=-1))
    return erfa.ab(sun / dist[..., None], v, dist, bm1) * (dist * AU)[..., None]


def _earth_rotation(epoch: Epoch, t: np.ndarray) -> np.ndarray:
    """GCRS → terrestrial (polar motion left out) matrices, (N, 3, 3)."""
    _, _, ut1, ut2 = epoch.dates(t)
    c2i = _interpolated(lambda s: erfa.c2i06a(*epoch.dates(s)[:2]), t, ROTATION_NODE_S)
    era = erfa.era00(ut1, ut2)
    c, s = np.cos(era), np.sin(era)
    R3 = np.zeros((*era.shape, 3, 3))  # erfa.rz(era): rotation of the frame about z
    R3[..., 0, 0], R3[..., 0, 1], R3[..., 1, 0], R3[..., 1, 1] = c, s, -s, c
    R3[..., 2, 2] = 1.0
    return R3 @ c2i


def _orbital_axes(longitude_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The satellite's terrestrial position (m) and the orbital frame's axes as rows."""
    lon = math.radians(longitude_deg)
    up = np.array([math.cos(lon), math.sin(lon), 0.0])
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    return GEO_RADIUS * up, np.array([east, [0.0, 0.0, -1.0], -up])  # x east, y south, z nadir


def sun_moon_orbital(epoch: Epoch, longitude_deg: float, t) -> tuple[np.ndarray, np.ndarray]:
    """Sun and Moon relative to a GEO satellite at ``longitude_deg``, orbital frame, metres.

    Parameters
    ----------
    epoch : Epoch
    longitude_deg : float
        Station longitude, degrees east.
    t : array_like, shape (N,)
        Seconds after the epoch (TAI, uniform through leap seconds).

    Returns
    -------
    sun, moon : ndarray, shape (N, 3)
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    M = _earth_rotation(epoch, t)
    sun = _interpolated(lambda s: _sun_gcrs(epoch, s), t, SUN_NODE_S)
    # the Moon too (it moves 0.009° a minute: a linear chord is off by ~1 m at 3.8e8 m);
    # moon98 at every second was a fifth of a real-sky run's time
    moon = _interpolated(lambda s: erfa.moon98(*epoch.dates(s)[:2])["p"] * AU, t, SUN_NODE_S)
    r_sat, axes = _orbital_axes(longitude_deg)
    out = []
    for body in (sun, moon):
        terrestrial = np.einsum("nij,nj->ni", M, body) - r_sat
        out.append(terrestrial @ axes.T)
    return out[0], out[1]


def occulted_fraction(a, b, c) -> np.ndarray:
    """Share of a disc of angular radius ``a`` covered by a disc of radius ``b`` at centre
    separation ``c`` (rad; arrays broadcast), 0…1 (Montenbruck & Gill eq. 3.86).

    Parameters
    ----------
    a : array_like
        Angular radius of the occulted disc, rad.
    b : array_like
        Angular radius of the occulting disc, rad.
    c : array_like
        Separation of the centres, rad.

    Returns
    -------
    numpy.ndarray
        The covered share, broadcast shape.
    """
    a, b, c = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (a, b, c)))
    out = np.zeros(a.shape)
    full = c <= b - a  # the occulter covers the whole disc
    ring = c <= a - b  # the occulter lies inside the disc (an annular eclipse)
    part = ~(full | ring) & (c < a + b)
    out[full] = 1.0
    out[ring] = (b[ring] / a[ring]) ** 2
    ap, bp, cp = a[part], b[part], c[part]
    x = (cp * cp + ap * ap - bp * bp) / (2 * cp)
    y = np.sqrt(np.maximum(ap * ap - x * x, 0.0))
    area = (
        ap * ap * np.arccos(np.clip(x / ap, -1, 1))
        + bp * bp * np.arccos(np.clip((cp - x) / bp, -1, 1))
        - cp * y
    )
    out[part] = area / (math.pi * ap * ap)
    return np.clip(out, 0.0, 1.0)


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between rows of u and v, rad (atan2: exact near 0 and π)."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def sky_table(sun: np.ndarray, moon: np.ndarray) -> np.ndarray:
    """The kernel's sky table from satellite-relative Sun and Moon positions (orbital frame, m).

    Returns (N, 9), columns :data:`SKY_COLUMNS`: unit Sun and Moon directions;
    ``sunlit`` = the share of the Sun's disc neither the Earth nor the Moon
    hides (the SRP scale); ``earth_lit`` = the same for the Earth alone (< 1: in
    the Earth's umbra or penumbra); ``moon_visible`` = 1 where the Moon is not
    behind the Earth; ``srp_scale`` = sunlit × (1 AU / Sun distance)²: solar pressure
    falls with the square of the distance (±3.4 % over the year).

    Parameters
    ----------
    sun, moon : numpy.ndarray, shape (N, 3)
        Satellite-relative positions in the orbital frame, m.

    Returns
    -------
    numpy.ndarray, shape (N, len(SKY_COLUMNS))
        Columns :data:`SKY_COLUMNS`.
    """
    earth = np.broadcast_to([0.0, 0.0, GEO_RADIUS], sun.shape)
    d_sun = np.linalg.norm(sun, axis=-1)
    d_moon = np.linalg.norm(moon, axis=-1)
    a_sun = np.arcsin(SUN_RADIUS / d_sun)
    a_earth = math.asin(EARTH_RADIUS / GEO_RADIUS)
    by_earth = occulted_fraction(a_sun, a_earth, _angle(sun, earth))
    by_moon = occulted_fraction(a_sun, np.arcsin(MOON_RADIUS / d_moon), _angle(sun, moon))
    moon_visible = _angle(moon, earth) > a_earth
    table = np.empty((sun.shape[0], len(SKY_COLUMNS)))
    table[:, :3] = sun / d_sun[:, None]
    table[:, 3:6] = moon / d_moon[:, None]
    table[:, 6] = (1 - by_earth) * (1 - by_moon * moon_visible)  # both at once: a bound
    table[:, 7] = 1 - by_earth
    table[:, 8] = moon_visible
    table[:, 9] = table[:, 6] * (AU / d_sun) ** 2
    return table

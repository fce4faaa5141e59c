"""Reading elevation files: what they hold and what they say about it (thesis 3.5.2).

A height map of the thesis is one height per sample on a regular grid (Fig. 3.16).
Elevation files say more: how far apart the samples are on the ground and in which
unit the heights are.  :func:`read_heightmap` returns both with the samples, so that
:func:`jaxgfx.terrain.heightmap_terrain` can build the terrain with true proportions.

Formats (chosen by the file name's suffix):

* GeoTIFF ``.tif`` / ``.tiff`` (SRTM, Copernicus DEM, USGS 3DEP, OpenTopography
  exports), read with ``tifffile`` (no GDAL; ``imagecodecs`` decodes LZW, DEFLATE with
  predictors, ...).  The sample spacing comes from ModelPixelScaleTag (33550) or an
  axis-aligned ModelTransformationTag (34264; rotated or sheared grids are refused);
  the GeoKeyDirectoryTag (34735) says whether it is in degrees (geographic,
  GTModelTypeGeoKey 1024 = 2) or in a projected CRS's linear unit
  (ProjLinearUnitsGeoKey 3076: metre, foot, US survey foot); VerticalUnitsGeoKey
  (4099) gives the height unit (default metres).  A TIFF without GeoTIFF tags is a
  plain image.  No reprojection is needed: a terrain wants the ground distance
  between neighbouring samples, not a different grid.
* SRTM ``.hgt``: a square of big-endian int16 metres, ``n`` samples spanning one
  degree (1201: 3 arc-seconds, 3601: 1 arc-second), its south-west corner in the
  name (``N46W123.hgt``).
* ESRI ASCII grid ``.asc``: ``ncols``/``nrows``/``xllcorner``/``yllcorner``/
  ``cellsize`` (or ``dx``/``dy``)/``NODATA_value`` then the rows, north first.  The
  CRS comes from a ``.prj`` beside it (``GEOGCS``: degrees; ``PROJCS``: its linear
  ``UNIT``); without one, a cell size under 0.01 on coordinates within +-180/+-90 is
  taken as degrees, anything else as metres (a 1 cm terrain grid is implausible, a
  36 arc-second one common).
* USGS ASCII DEM ``.dem`` (type A header + type B profiles).
* ``.npy`` / ``.npz`` arrays and images (PNG, JPEG, plain TIFF, ...): no units.

Geographic spacings become metres at the map's centre latitude, per axis, on the
WGS 84 ellipsoid: a degree of latitude is the meridian's radius of curvature
``M(phi) pi / 180``, a degree of longitude ``N(phi) cos(phi) pi / 180`` (3 arc-seconds
are 74.6 m east-west by 92.5 m north-south at 36.6 N).

NODATA: every format marks its voids in its own way, and the file's own marker is read:
a GeoTIFF's GDAL_NODATA tag (42113, e.g. ``-32768`` or ``nan``; NaN samples always), an
SRTM tile's -32768, an ASCII grid's ``NODATA_value`` (-9999 when the header has none, as
the format defines), a USGS DEM's -32767 (its profiles' void value).  Voids are filled
from their known neighbours, ring by ring (:func:`_fill_outside`), as are a USGS DEM's
grid corners outside its quad (no samples, not voids); :class:`HeightmapData` counts both,
and :func:`read_heightmap` warns (:class:`NodataWarning`) with the count and the share of
the map when a file has voids.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from typing import NamedTuple

import numpy as np

__all__ = [
    "HeightmapData",
    "NodataWarning",
    "read_heightmap",
    "load_heightmap",
    "metres_per_degree",
]

_METRES_PER_FOOT = 0.3048
_METRES_PER_US_SURVEY_FOOT = 1200.0 / 3937.0
_METRES_PER_ARC_SECOND = 30.87
"""One arc-second of latitude (USGS DEM headers give geographic spacing in arc-seconds)."""
_DEM_VOID = -32767
"""A USGS DEM profile's void elevation (as GDAL's USGSDEM driver reads it)."""
_HGT_VOID = -32768
"""An SRTM tile's void."""
_ASC_NODATA = -9999.0
"""An ESRI ASCII grid's NODATA value when its header gives none (the format's default)."""
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3
# EPSG linear and angular unit codes of GeoTIFF's GeoKeys
_LINEAR_UNITS = {9001: 1.0, 9002: _METRES_PER_FOOT, 9003: _METRES_PER_US_SURVEY_FOOT, 9036: 1e3}
_LINEAR_NAMES = {9001: "metre", 9002: "foot", 9003: "US survey foot", 9036: "kilometre"}
_DEGREES_PER_ANGULAR_UNIT = {9102: 1.0, 9101: 180.0 / math.pi, 9105: 0.9, 9122: 1.0}


class HeightmapData(NamedTuple):
    """An elevation file's samples and what the file says about them.

    Attributes:
        heights: (H, W) float64 values as the file gives them (DEMs: elevations in the
            file's height unit; images: grey levels, RGB averaged; arrays: as stored).
            Row 0 is north (the image's top row); NODATA samples are already filled.
        spacing: (x, z) metres between neighbouring samples along a row (east) and
            along a column (south), or None when the file does not say (images, arrays).
        height_unit: metres per height unit (1.0 for metres, 0.3048 for feet), or None.
        crs: what the file says its grid is in, e.g. ``"EPSG:4326"``, ``"EPSG:32610"``,
            ``"geographic (assumed)"``; None for files without units.
        filled: number of samples filled from their neighbours: the NODATA voids and, in
            a USGS DEM, the grid's corners outside the quad.
        nodata: number of those the file marks NODATA (voids; NaN samples included).
        nodata_value: the file's NODATA marker (NaN for a GeoTIFF whose tag says ``nan``),
            None for files without one (images, arrays, a GeoTIFF without the tag).
    """

    heights: np.ndarray
    spacing: tuple[float, float] | None
    height_unit: float | None
    crs: str | None = None
    filled: int = 0
    nodata: int = 0
    nodata_value: float | None = None


class NodataWarning(UserWarning):
    """An elevation file has NODATA voids; :func:`read_heightmap` filled them.

    The message names the file, the number of voids and their share of the map.  Filter it
    as any warning: ``warnings.simplefilter("ignore", NodataWarning)``.
    """


def metres_per_degree(latitude: float) -> tuple[float, float]:
    """(east-west, north-south) metres per degree at ``latitude`` degrees (WGS 84)."""
    phi = math.radians(latitude)
    w = 1.0 - _WGS84_E2 * math.sin(phi) ** 2
    meridian = _WGS84_A * (1.0 - _WGS84_E2) / w**1.5  # M(phi)
    normal = _WGS84_A / math.sqrt(w)  # N(phi)
    return normal * math.cos(phi) * math.pi / 180.0, meridian * math.pi / 180.0


def _fill_outside(grid: np.ndarray) -> np.ndarray:
    """NaN cells take the mean of their known 4-neighbours, ring by ring (outwards).

    A USGS DEM's quad is rotated against the UTM grid, so profiles start and end at
    different rows and the grid's corners outside the quad have no samples; GeoTIFF,
    SRTM and ASCII grids mark voids with NODATA.  Growing the known samples into the
    holes continues the ground smoothly; the lowest height would dig a moat around
    the map and a pit at every void.
    """
    grid = grid.copy()
    known = ~np.isnan(grid)
    if not known.any():
        raise ValueError("no samples")
    while not known.all():
        val = np.pad(np.where(known, grid, 0.0), 1)
        cnt = np.pad(known.astype(np.float64), 1)
        total = val[:-2, 1:-1] + val[2:, 1:-1] + val[1:-1, :-2] + val[1:-1, 2:]
        n = cnt[:-2, 1:-1] + cnt[2:, 1:-1] + cnt[1:-1, :-2] + cnt[1:-1, 2:]
        grow = ~known & (n > 0)
        grid[grow] = total[grow] / n[grow]
        known = known | grow
    return grid


def _nodata_mask(arr: np.ndarray, nodata: float | None) -> np.ndarray:
    """Where ``arr`` holds the NODATA marker ``nodata`` or is not finite.

    The marker is compared in the array's own type: a float32 map marked ``-9999.9`` holds
    the float32 nearest to it, not the float64, and an integer map matches only an
    integer marker within its range.
    """
    a = np.asarray(arr)
    missing = ~np.isfinite(a) if np.issubdtype(a.dtype, np.floating) else np.zeros(a.shape, bool)
    if nodata is None or not math.isfinite(nodata):
        return missing
    if np.issubdtype(a.dtype, np.integer):
        info = np.iinfo(a.dtype)
        if nodata != int(nodata) or not info.min <= nodata <= info.max:
            return missing
        return missing | (a == int(nodata))
    if np.issubdtype(a.dtype, np.floating):
        return missing | (a == np.asarray(nodata).astype(a.dtype))
    return missing | (a == nodata)


def _with_nodata(arr: np.ndarray, nodata: float | None, path: str) -> tuple[np.ndarray, int]:
    """float64 ``arr`` with NODATA (and NaN) samples filled; (heights, number filled)."""
    missing = _nodata_mask(arr, nodata)
    h = np.asarray(arr, np.float64)
    if missing.all():
        raise ValueError(f"heightmap {path!r} has no valid samples (all NODATA)")
    if not missing.any():
        return h, 0
    return _fill_outside(np.where(missing, np.nan, h)), int(missing.sum())


def _header_int(header: str, a: int, b: int) -> int | None:
    try:
        return int(header[a:b])
    except ValueError:
        return None


# --------------------------------------------------------------------------------------
# USGS ASCII DEM
# --------------------------------------------------------------------------------------


def _parse_usgs_dem(data: bytes, path: str) -> HeightmapData:
    """USGS ASCII DEM (type A header + type B profiles) -> heights and spacing.

    Type A record fields (0-based byte ranges): ground unit 528:534 (0 radians,
    1 feet, 2 metres, 3 arc-seconds), elevation unit 534:540 (1 feet, 2 metres),
    spatial resolution x, y, z 816:852 (3 x E12.6), profile count 858:864.  Each
    type B profile holds 9 header tokens (row, column, m, n, x, y, local datum,
    min, max) and m elevations; elevation = datum + value * z resolution.
    """
    header = data[:1024].decode("ascii", errors="replace")
    try:
        dx = float(header[816:828].replace("D", "E"))
        dy = float(header[828:840].replace("D", "E"))
        dz = float(header[840:852].replace("D", "E"))
        n_profiles = int(header[858:864])
        tokens = data[1024:].decode("ascii").replace("D", "E").split()
        pos = 0
        profiles = []
        for _ in range(n_profiles):
            m = int(tokens[pos + 2])
            y0 = float(tokens[pos + 5])
            datum = float(tokens[pos + 6])
            elev = np.asarray(tokens[pos + 9 : pos + 9 + m], dtype=np.float64)
            if elev.size != m:
                raise ValueError("truncated profile")
            scaled = datum + elev * (dz if dz > 0 else 1.0)
            profiles.append((y0, np.where(elev == _DEM_VOID, np.nan, scaled)))
            pos += 9 + m
    except (ValueError, IndexError, UnicodeDecodeError) as err:
        raise ValueError(f"heightmap {path!r} is not a readable USGS ASCII DEM: {err}") from None
    if not profiles or dy <= 0:
        raise ValueError(f"heightmap {path!r} has no elevation profiles")
    y_lo = min(p[0] for p in profiles)
    rows = max(int(round((p[0] - y_lo) / dy)) + p[1].size for p in profiles)
    grid = np.full((rows, len(profiles)), np.nan)
    for c, (y0, elev) in enumerate(profiles):
        r = int(round((y0 - y_lo) / dy))
        grid[r : r + elev.size, c] = elev
    voids = sum(int(np.isnan(p[1]).sum()) for p in profiles)
    filled = int(np.isnan(grid).sum())
    if filled == grid.size:
        raise ValueError(f"heightmap {path!r} has no valid samples (all NODATA)")
    grid = _fill_outside(grid)
    ground_unit = _header_int(header, 528, 534)
    ground = {1: _METRES_PER_FOOT, 2: 1.0}.get(ground_unit or -1)
    spacing = None if ground is None or dx <= 0 else (dx * ground, dy * ground)
    if ground_unit == 3 and dx > 0:  # arc-seconds: metres at the quad's latitude
        try:
            ys = [float(header[570 + 48 * i : 594 + 48 * i].replace("D", "E")) for i in range(4)]
            mx, mz = metres_per_degree(float(np.mean(ys)) / 3600.0)
            spacing = (dx * mx / 3600.0, dy * mz / 3600.0)
        except ValueError:
            spacing = (dx * _METRES_PER_ARC_SECOND, dy * _METRES_PER_ARC_SECOND)
    unit = {1: _METRES_PER_FOOT, 2: 1.0}.get(_header_int(header, 534, 540) or -1)
    crs = {1: "UTM", 2: "State Plane"}.get(_header_int(header, 156, 162) or -1)
    # north at row 0, like an image
    nodata = float(_DEM_VOID)
    return HeightmapData(grid[::-1], spacing, unit, crs or "USGS DEM", filled, voids, nodata)


# --------------------------------------------------------------------------------------
# GeoTIFF
# --------------------------------------------------------------------------------------


def _geo_keys(directory, doubles, ascii_params) -> dict[int, object]:
    """GeoKeyDirectoryTag (34735) -> {key id: value} (shorts, doubles or strings)."""
    d = [int(v) for v in directory]
    if len(d) < 4:
        return {}
    keys: dict[int, object] = {}
    for i in range(d[3]):
        key, loc, count, off = d[4 + 4 * i : 8 + 4 * i]
        if loc == 0:
            keys[key] = off
        elif loc == 34736 and doubles is not None:
            vals = tuple(float(v) for v in doubles[off : off + count])
            keys[key] = vals[0] if count == 1 else vals
        elif loc == 34737 and ascii_params is not None:
            keys[key] = ascii_params[off : off + count].rstrip("|\x00")
    return keys


def _read_geotiff(path: str) -> HeightmapData | None:
    """A GeoTIFF's heights and spacing, or None for a TIFF without GeoTIFF tags."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            tags = {t.code: t.value for t in page.tags.values()}
            if 33550 not in tags and 34264 not in tags:
                return None
            arr = page.asarray()
    except (tifffile.TiffFileError, ValueError, KeyError, OSError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"heightmap {path!r} is not a readable GeoTIFF: {first}") from None
    if arr.ndim == 3 and arr.shape[-1] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise ValueError(
            f"heightmap {path!r}: a GeoTIFF elevation model has one band, got shape {arr.shape}"
        )
    keys = _geo_keys(tags.get(34735, ()), tags.get(34736), tags.get(34737))
    if 34264 in tags:
        m = np.asarray(tags[34264], np.float64).reshape(4, 4)
        if abs(m[0, 1]) > 1e-12 * abs(m[0, 0]) or abs(m[1, 0]) > 1e-12 * abs(m[1, 1]):
            raise ValueError(
                f"heightmap {path!r}: the GeoTIFF's grid is rotated or sheared "
                "(ModelTransformationTag); warp it north-up first, e.g. gdalwarp"
            )
        sx, sy = abs(m[0, 0]), abs(m[1, 1])
        y0 = m[1, 3]
        north_up = m[1, 1] < 0
    else:
        scale = tags[33550]
        sx, sy = float(scale[0]), float(scale[1])
        tie = tags.get(33922, (0, 0, 0, 0, 0, 0))
        y0 = float(tie[4]) + float(tie[1]) * sy  # y of row 0
        north_up = sy > 0  # the GeoTIFF convention: y decreases down the rows
        sx, sy = abs(sx), abs(sy)
    if not (sx > 0 and sy > 0 and math.isfinite(sx) and math.isfinite(sy)):
        raise ValueError(f"heightmap {path!r}: GeoTIFF pixel size ({sx}, {sy}) must be > 0")
    model = keys.get(1024)
    if model == 2:  # geographic: degrees (or another angular unit)
        angular = keys.get(2054, 9102)
        if angular not in _DEGREES_PER_ANGULAR_UNIT:
            raise ValueError(f"heightmap {path!r}: unsupported GeoTIFF angular unit {angular}")
        deg = _DEGREES_PER_ANGULAR_UNIT[angular]
        rows = arr.shape[0]
        lat = (y0 - (rows / 2) * sy) * deg if north_up else (y0 + (rows / 2) * sy) * deg
        if not -90.0 <= lat <= 90.0:
            raise ValueError(f"heightmap {path!r}: GeoTIFF centre latitude {lat:g} is not in +-90")
        mx, mz = metres_per_degree(lat)
        spacing = (sx * deg * mx, sy * deg * mz)
        code = keys.get(2048)
        crs = f"EPSG:{code}" if isinstance(code, int) and code < 32767 else "geographic"
    elif model == 1:  # projected: the CRS's linear unit
        code = keys.get(3072)
        unit = keys.get(3076)
        if unit is None:
            unit = 9001  # every UTM zone (326xx, 327xx) and most projected CRSs
        if unit not in _LINEAR_UNITS:
            raise ValueError(
                f"heightmap {path!r}: unsupported GeoTIFF linear unit {unit} (metre 9001, "
                "foot 9002, US survey foot 9003 and kilometre 9036 are read)"
            )
        spacing = (sx * _LINEAR_UNITS[unit], sy * _LINEAR_UNITS[unit])
        crs = f"EPSG:{code}" if isinstance(code, int) and code < 32767 else "projected"
    elif model == 3:
        raise ValueError(f"heightmap {path!r}: geocentric GeoTIFFs are not height maps")
    else:
        raise ValueError(
            f"heightmap {path!r}: the GeoTIFF does not say whether its grid is geographic or "
            "projected (GTModelTypeGeoKey); pass it as a plain image with --vertical-scale"
        )
    vunit = keys.get(4099, 9001)
    height_unit = _LINEAR_UNITS.get(vunit, 1.0) if isinstance(vunit, int) else 1.0
    nodata = None
    if 42113 in tags:
        try:
            nodata = float(str(tags[42113]).strip("\x00 "))
        except ValueError:
            nodata = None
    heights, filled = _with_nodata(arr, nodata, path)
    if not north_up:
        heights = heights[::-1]
    mx, mz = float(spacing[0]), float(spacing[1])
    return HeightmapData(heights, (mx, mz), height_unit, crs, filled, filled, nodata)


# --------------------------------------------------------------------------------------
# SRTM .hgt and ESRI ASCII grids
# --------------------------------------------------------------------------------------


_HGT_NAME = re.compile(r"^([NS])(\d{1,2})([EW])(\d{1,3})", re.IGNORECASE)


def _read_hgt(path: str) -> HeightmapData:
    """SRTM ``.hgt``: n x n big-endian int16 metres over one degree; void -32768."""
    size = os.path.getsize(path)
    n = math.isqrt(size // 2)
    if n < 2 or n * n * 2 != size:
        raise ValueError(
            f"heightmap {path!r} is not an SRTM .hgt tile (n x n big-endian int16 samples), "
            f"its {size} bytes are not 2 n^2"
        )
    m = _HGT_NAME.match(os.path.basename(path))
    if m is None:
        raise ValueError(
            f"heightmap {path!r}: an SRTM .hgt tile is named after its south-west corner, "
            "e.g. N46W123.hgt; the name says where it lies (and so its metres per degree)"
        )
    lat0 = int(m.group(2)) * (1 if m.group(1).upper() == "N" else -1)
    arr = np.fromfile(path, dtype=">i2").reshape(n, n)
    mx, mz = metres_per_degree(lat0 + 0.5)
    step = 1.0 / (n - 1)  # the tile's edges are shared with its neighbours
    heights, filled = _with_nodata(arr, _HGT_VOID, path)
    spacing = (step * mx, step * mz)
    return HeightmapData(heights, spacing, 1.0, "EPSG:4326", filled, filled, float(_HGT_VOID))


def _asc_crs(path: str) -> tuple[str, float] | None:
    """(crs, metres per unit) from a ``.prj`` beside an ASCII grid, or None."""
    stem = os.path.splitext(path)[0]
    for prj in (stem + ".prj", stem + ".PRJ"):
        if os.path.isfile(prj):
            with open(prj, encoding="ascii", errors="replace") as fh:
                wkt = fh.read()
            if wkt.lstrip().upper().startswith(("PROJCS", "PROJCRS")):
                units = re.findall(r'UNIT\["([^"]*)"\s*,\s*([0-9.eE+-]+)', wkt)
                factor = float(units[-1][1]) if units else 1.0
                return "projected (.prj)", factor
            if wkt.lstrip().upper().startswith(("GEOGCS", "GEOGCRS")):
                return "geographic (.prj)", -1.0
    return None


def _read_asc(path: str) -> HeightmapData:
    """ESRI ASCII grid: a header of ``key value`` lines, then nrows rows, north first."""
    header: dict[str, float] = {}
    try:
        with open(path, encoding="ascii") as fh:
            while True:
                pos = fh.tell()
                line = fh.readline()
                parts = line.split()
                if not parts:
                    if not line:
                        break
                    continue
                if parts[0][:1].isalpha():
                    header[parts[0].lower()] = float(parts[1])
                else:
                    fh.seek(pos)
                    break
            values = np.array(fh.read().split(), dtype=np.float64)
        cols, rows = int(header["ncols"]), int(header["nrows"])
        if "cellsize" in header:
            dx = dy = header["cellsize"]
        else:
            dx, dy = header["dx"], header["dy"]
        x0 = header.get("xllcorner", header.get("xllcenter"))
        y0 = header.get("yllcorner", header.get("yllcenter"))
    except (KeyError, ValueError, IndexError, UnicodeDecodeError) as err:
        raise ValueError(
            f"heightmap {path!r} is not a readable ESRI ASCII grid: missing or bad {err}"
        ) from None
    if values.size != rows * cols or rows < 1 or cols < 1:
        raise ValueError(
            f"heightmap {path!r}: an ESRI ASCII grid of {rows} x {cols} needs {rows * cols} "
            f"values, found {values.size}"
        )
    if not (dx > 0 and dy > 0):
        raise ValueError(f"heightmap {path!r}: cell size ({dx}, {dy}) must be > 0")
    crs = _asc_crs(path)
    if crs is None:
        geographic = (
            max(dx, dy) < 0.01
            and x0 is not None
            and y0 is not None
            and -180 <= x0 <= 360
            and -90 <= y0 <= 90
            and y0 + rows * dy <= 90
        )
        crs = ("geographic (assumed)", -1.0) if geographic else ("projected (assumed metres)", 1.0)
    nodata = header.get("nodata_value", _ASC_NODATA)
    heights, filled = _with_nodata(values.reshape(rows, cols), nodata, path)
    if crs[1] < 0:
        lat = (y0 or 0.0) + rows * dy / 2
        mx, mz = metres_per_degree(lat)
        spacing = (dx * mx, dy * mz)
    else:
        spacing = (dx * crs[1], dy * crs[1])
    return HeightmapData(heights, spacing, 1.0, crs[0], filled, filled, nodata)


# --------------------------------------------------------------------------------------
# Any height map
# --------------------------------------------------------------------------------------


def _read_image(path: str) -> np.ndarray:
    import imageio.v3 as iio

    try:
        return np.asarray(iio.imread(path))
    except Exception:  # imageio raises many types for unreadable files
        raise ValueError(
            f"heightmap {path!r} is not a readable image or elevation file (PNG, JPEG, TIFF, "
            "GeoTIFF, .hgt, .asc, .dem, .npy)"
        ) from None


def read_heightmap(path: str | os.PathLike) -> HeightmapData:
    """Reads an elevation file and what it says about itself (see the module docstring).

    GeoTIFF (``.tif``, ``.tiff``), SRTM ``.hgt``, ESRI ASCII ``.asc`` and USGS ``.dem``
    give their sample spacing in metres (geographic spacings converted at the map's
    latitude) and their height unit; images and ``.npy``/``.npz`` arrays give neither
    (``spacing`` and ``height_unit`` are None).  NODATA samples (the file's own marker,
    see the module docstring) are filled from their neighbours, counted in ``nodata`` and
    ``filled``, and reported by a :class:`NodataWarning` naming the file, the count and
    their share of the map.

    Returns:
        :class:`HeightmapData` with (H, W) float64 ``heights``, row 0 north.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``path`` is a directory, or not a readable elevation file or image,
            or not 2-D and finite (one line naming the file and the cause).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"heightmap path {path!r} is a directory, not an elevation file or image")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"heightmap path {path!r} does not exist")
    data = _read_elevation(path)
    if data is None:
        return HeightmapData(_read_array(path), None, None)
    if data.nodata:
        n, value = data.heights.size, data.nodata_value
        marker = "NaN" if value is None or math.isnan(value) else f"{value:g}"
        warnings.warn(
            NodataWarning(
                f"heightmap {path!r}: {data.nodata} of {n} samples ({100 * data.nodata / n:.3g} "
                f"%) are NODATA ({marker}), filled from their neighbours"
            ),
            stacklevel=2,
        )
    return data


def _read_elevation(path: str) -> HeightmapData | None:
    """An elevation file's data by its suffix; None for images and arrays."""
    lower = path.lower()
    if lower.endswith(".dem"):
        with open(path, "rb") as fh:
            return _parse_usgs_dem(fh.read(), path)
    if lower.endswith(".hgt"):
        return _read_hgt(path)
    if lower.endswith(".asc"):
        return _read_asc(path)
    if lower.endswith((".tif", ".tiff")):
        return _read_geotiff(path)
    return None


def _read_array(path: str) -> np.ndarray:
    """The (H, W) float64 values of an image or a ``.npy``/``.npz`` array (no units)."""
    lower = path.lower()
    if lower.endswith((".npy", ".npz")):
        try:
            arr = np.load(path)
        except (ValueError, OSError, EOFError):
            raise ValueError(f"heightmap {path!r} is not a readable NumPy array file") from None
        if isinstance(arr, np.lib.npyio.NpzFile):
            arr = arr[arr.files[0]]
    else:
        arr = _read_image(path)
    arr = np.asarray(arr, np.float64)
    if arr.ndim == 3:
        arr = arr[..., :3].mean(axis=-1)
    if arr.ndim != 2 or min(arr.shape) < 1:
        raise ValueError(f"heightmap {path!r} must be 2-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"heightmap {path!r} contains non-finite values")
    return arr


def load_heightmap(path: str | os.PathLike) -> np.ndarray:
    """The (H, W) float64 heights of :func:`read_heightmap` (file units, grey levels)."""
    return read_heightmap(path).heights

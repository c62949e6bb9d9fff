"""Scene descriptions (TOML): HDR content, motion, sensor geometry, readout and effects.

A scene file has top-level keys ``description``, ``width``, ``height`` (the *raw* sensor size;
``binned`` halves it), ``rate_hz``, ``duration_s``, ``exposure`` (expected photo-electrons per
readout interval at unit radiance), ``seed``, ``effects`` (list of names from
``rmbvideo.sensor.effects.EFFECTS``), ``subsamples`` (time samples per interval for motion blur) and
tables:

- ``[readout]``: ``type`` (1bit, Lbit, rmb, binned), ``level``, ``band``, ``shift``.
- ``[sensor]``: overrides of ``SensorParams`` fields (``reset = "subtract"`` for a pixel that keeps the charge past
  its threshold, as real spiking cameras do), plus ``dark_correlation_px``.
- ``[background]``: ``panorama`` (bundled name or path to an EXR), ``gain``, ``center`` (panorama
  px at t=0), ``velocity`` (panorama px/s), ``zoom`` (image px per panorama px), ``zoom_rate``
  (zoom(t) = zoom * exp(zoom_rate * t)).
- ``[[objects]]``: textured shapes moving in image space over the background, drawn in file order
  (later on top): ``shape`` (rect, ellipse), ``size`` [w, h] px, ``position`` [x, y] px at t=0,
  ``velocity`` px/s, ``angle_deg``, ``angular_velocity_deg`` (deg/s), ``texture`` (``checker``,
  ``uniform``, ``led`` or ``panorama:NAME``), ``radiance`` (multiplier: light sources use 1e3-1e5),
  ``crop`` [x, y, w, h] of the panorama for ``panorama:`` textures, ``grid`` [cols, rows] of
  ``led`` arrays.
- ``[[dark_regions]]``: attenuation masks fixed to the background: ``rect`` [x, y, w, h] in
  panorama px, ``attenuation`` (factor < 1), ``softness`` (edge blur in px).

Radiance is luminance of the panorama divided by its median, times ``gain``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

from rmbvideo.errors import InputError
from rmbvideo.io.dat import MAX_RATE_HZ, MIN_RATE_HZ
from rmbvideo.sensor.effects import EFFECTS
from rmbvideo.sensor.emission import READOUT_KINDS, ReadoutSpec
from rmbvideo.sensor.params import RESETS, SensorParams

BUNDLED_PACKAGE = "rmbvideo.scenes"
# Limits that keep a typo from hanging the simulator or exhausting memory; each is far beyond any real use.
MAX_SIDE = 8192
MAX_PIXELS = 2048 * 2048  # larger than any spiking camera (1000 x 1000 is the largest we know)
MAX_DURATION_S = 3600.0
MAX_SUBSAMPLES = 64
MAX_ZOOM = 1000.0  # zoom(t) must stay within [1 / MAX_ZOOM, MAX_ZOOM] over the whole scene
MAX_COORDINATE = 1e6  # px or px/s: positions, sizes, velocities, rectangles
MAX_GRID = 256
TEXTURES = ("checker", "uniform", "led")
SHAPES = ("rect", "ellipse")


@dataclass(frozen=True)
class Background:
    """A panorama seen through a camera that pans (linear velocity) and zooms (exponential)."""

    panorama: str = "city"
    gain: float = 1.0
    center: tuple[float, float] = (512.0, 256.0)
    velocity: tuple[float, float] = (0.0, 0.0)
    zoom: float = 1.0
    zoom_rate: float = 0.0


@dataclass(frozen=True)
class SceneObject:
    """A textured shape moving (and rotating) in image space in front of the background."""

    shape: str = "rect"
    size: tuple[float, float] = (40.0, 30.0)
    position: tuple[float, float] = (0.0, 0.0)
    velocity: tuple[float, float] = (0.0, 0.0)
    angle_deg: float = 0.0
    angular_velocity_deg: float = 0.0
    texture: str = "checker"
    radiance: float = 1.0
    crop: tuple[float, float, float, float] | None = None
    grid: tuple[int, int] = (4, 3)


@dataclass(frozen=True)
class DarkRegion:
    """A soft-edged rectangle of the panorama attenuated by ``attenuation`` (deep shadow)."""

    rect: tuple[float, float, float, float]
    attenuation: float = 1e-2
    softness: float = 4.0


@dataclass(frozen=True)
class Scene:
    """Everything needed to simulate a capture and its ground truth."""

    name: str
    description: str = ""
    width: int = 400
    height: int = 250
    rate_hz: float = 20000.0
    duration_s: float = 0.1
    exposure: float = 15.0
    seed: int = 0
    effects: tuple[str, ...] = ()
    subsamples: int = 1
    readout: ReadoutSpec = field(default_factory=ReadoutSpec)
    sensor: SensorParams = field(default_factory=SensorParams)
    dark_correlation_px: float = 1.5
    background: Background = field(default_factory=Background)
    objects: tuple[SceneObject, ...] = ()
    dark_regions: tuple[DarkRegion, ...] = ()
    source: Path | None = None

    @property
    def total_readouts(self) -> int:
        """Raw readouts in ``duration_s`` (even for ``binned``, so every bin is complete)."""
        count = int(math.floor(self.duration_s * self.rate_hz + 1e-9))
        return count - count % 2 if self.readout.kind == "binned" else count

    @property
    def output_size(self) -> tuple[int, int]:
        """(width, height) of the stream after readout (half the raw size for ``binned``)."""
        if self.readout.kind == "binned":
            return self.width // 2, self.height // 2
        return self.width, self.height


#: The bundled HDR panoramas (``NAME.exr``), named by ``panorama = "NAME"`` or a ``panorama:NAME`` texture
HDRI_DIR = Path(__file__).resolve().parent / "hdri"


def bundled_panoramas() -> list[str]:
    """Names of the bundled panoramas."""
    return sorted(p.stem for p in HDRI_DIR.glob("*.exr"))


def bundled_dir() -> Path:
    """Folder of the bundled scene files."""
    return Path(str(resources.files(BUNDLED_PACKAGE).joinpath("bundled")))


def bundled_scenes() -> dict[str, str]:
    """Bundled scene name -> one-line description."""
    scenes = {}
    for path in sorted(bundled_dir().glob("*.toml")):
        scenes[path.stem] = load_scene(path).description
    return scenes


def resolve_scene(name_or_path: str) -> Scene:
    """Load a bundled scene by name, or a scene file by path."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        return load_scene(path)
    bundled = bundled_dir() / f"{name_or_path}.toml"
    if bundled.is_file():
        return load_scene(bundled)
    names = ", ".join(sorted(p.stem for p in bundled_dir().glob("*.toml")))
    raise InputError(f"{name_or_path}: no such scene file or bundled scene (bundled: {names})")


def load_scene(path: Path) -> Scene:
    """Parse and validate a scene file; every problem is an ``InputError`` naming file and key."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: scene file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read scene file ({exc})") from None
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not valid TOML ({str(exc).splitlines()[0][:200]})") from None
    return _SceneParser(path).scene(data)


class _SceneParser:
    """Typed access to TOML tables with errors that name the file and the key."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, problem: str) -> InputError:
        return InputError(f"{self.path}: '{key}' {problem}")

    def number(self, table: dict, key: str, prefix: str, default: float, *, minimum: float | None = None,
               positive: bool = False, maximum: float | None = None) -> float:
        value = table.get(key, default)
        name = f"{prefix}{key}"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(name, f"must be a finite number, not {value!r}")
        if positive and value <= 0:
            raise self.fail(name, f"must be > 0, not {value!r}")
        if minimum is not None and value < minimum:
            raise self.fail(name, f"must be >= {minimum}, not {value!r}")
        if maximum is not None and abs(value) > maximum:
            raise self.fail(name, f"must be at most {maximum:g} in magnitude, not {value!r}")
        return float(value)

    def integer(self, table: dict, key: str, prefix: str, default: int, minimum: int,
                maximum: int | None = None) -> int:
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(f"{prefix}{key}", f"must be an integer >= {minimum}, not {value!r}")
        if maximum is not None and value > maximum:
            raise self.fail(f"{prefix}{key}", f"must be at most {maximum} (limit of this simulator), not {value!r}")
        return value

    def vector(self, table: dict, key: str, prefix: str, default: tuple, length: int,
               maximum: float = MAX_COORDINATE) -> tuple:
        value = table.get(key, default)
        if (not isinstance(value, (list, tuple)) or len(value) != length
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                       for v in value)):
            raise self.fail(f"{prefix}{key}", f"must be a list of {length} numbers, not {value!r}")
        if any(abs(v) > maximum for v in value):
            raise self.fail(f"{prefix}{key}", f"values must be at most {maximum:g} in magnitude, not {value!r}")
        return tuple(float(v) for v in value)

    def table(self, data: dict, key: str) -> dict:
        value = data.get(key, {})
        if not isinstance(value, dict):
            raise self.fail(key, "must be a table")
        return value

    def tables(self, data: dict, key: str) -> list[dict]:
        value = data.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.fail(key, "must be an array of tables ([[...]])")
        return value

    def check_keys(self, table: dict, allowed: set[str], prefix: str) -> None:
        extra = sorted(set(table) - allowed)
        if extra:
            raise self.fail(f"{prefix}{extra[0]}", f"is not a known key (known: {', '.join(sorted(allowed))})")

    def scene(self, data: dict[str, Any]) -> Scene:
        top = {"description", "width", "height", "rate_hz", "duration_s", "exposure", "seed", "effects",
               "subsamples", "readout", "sensor", "background", "objects", "dark_regions"}
        self.check_keys(data, top, "")
        description = data.get("description", "")
        if not isinstance(description, str):
            raise self.fail("description", "must be a string")
        effects = data.get("effects", [])
        if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
            raise self.fail("effects", "must be a list of effect names")
        for effect in effects:
            if effect not in EFFECTS:
                raise self.fail("effects", f"names unknown effect {effect!r} (known: {', '.join(EFFECTS)})")
        readout = self.readout(self.table(data, "readout"))
        width = self.integer(data, "width", "", 400, 8, MAX_SIDE)
        height = self.integer(data, "height", "", 250, 2, MAX_SIDE)
        if width * height > MAX_PIXELS:
            raise self.fail("width", f"x 'height' = {width * height} pixels is more than this simulator's limit "
                                     f"of {MAX_PIXELS} (larger than any spiking camera)")
        if readout.kind == "binned" and (width % 2 or height % 2):
            raise self.fail("width", "and 'height' must be even for the binned readout")
        sensor, correlation = self.sensor(self.table(data, "sensor"), readout)
        duration = self.number(data, "duration_s", "", 0.1, positive=True, maximum=MAX_DURATION_S)
        background = self.background(self.table(data, "background"))
        end_zoom = math.log(background.zoom) + background.zoom_rate * duration
        if abs(end_zoom) > math.log(MAX_ZOOM):
            raise self.fail("background.zoom_rate", f"takes the zoom outside [{1 / MAX_ZOOM:g}, {MAX_ZOOM:g}] "
                                                    f"within duration_s = {duration:g}")
        return Scene(
            name=self.path.stem,
            description=description,
            width=width,
            height=height,
            rate_hz=self.rate(data),
            duration_s=duration,
            exposure=self.number(data, "exposure", "", 15.0, minimum=0.0),
            seed=self.integer(data, "seed", "", 0, 0),
            effects=tuple(dict.fromkeys(effects)),
            subsamples=self.integer(data, "subsamples", "", 1, 1, MAX_SUBSAMPLES),
            readout=readout,
            sensor=sensor,
            dark_correlation_px=correlation,
            background=background,
            objects=tuple(self.scene_object(t, i) for i, t in enumerate(self.tables(data, "objects"))),
            dark_regions=tuple(self.dark_region(t, i) for i, t in enumerate(self.tables(data, "dark_regions"))),
            source=self.path,
        )

    def rate(self, data: dict) -> float:
        rate = self.number(data, "rate_hz", "", 20000.0, positive=True)
        if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
            raise self.fail("rate_hz", f"must be between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g} Hz, not {rate!r}")
        return rate

    def zoom(self, table: dict) -> float:
        zoom = self.number(table, "zoom", "background.", 1.0, positive=True)
        if not 1 / MAX_ZOOM <= zoom <= MAX_ZOOM:
            raise self.fail("background.zoom", f"must be between {1 / MAX_ZOOM:g} and {MAX_ZOOM:g}, not {zoom!r}")
        return zoom

    def readout(self, table: dict) -> ReadoutSpec:
        self.check_keys(table, {"type", "level", "band", "shift"}, "readout.")
        kind = table.get("type", "1bit")
        if kind not in READOUT_KINDS:
            raise self.fail("readout.type", f"must be one of {', '.join(READOUT_KINDS)}, not {kind!r}")
        level = self.integer(table, "level", "readout.", 7, 1)
        if (level + 1) & level or level > 255:
            raise self.fail("readout.level", f"must be 2^B - 1 up to 255 (1, 3, 7, 15, ...), not {level}")
        return ReadoutSpec(kind=kind, level=level, band=self.integer(table, "band", "readout.", 4, 1),
                           shift=self.integer(table, "shift", "readout.", 2, 1))

    def sensor(self, table: dict, readout: ReadoutSpec) -> tuple[SensorParams, float]:
        names = {f.name for f in fields(SensorParams)} - {"level", "reset"}
        self.check_keys(table, names | {"dark_correlation_px", "reset"}, "sensor.")
        defaults = SensorParams()
        values: dict = {name: self.number(table, name, "sensor.", getattr(defaults, name), minimum=0.0)
                        for name in names if name in table}
        if "reset" in table:
            if table["reset"] not in RESETS:
                raise self.fail("sensor.reset", f"must be one of {', '.join(RESETS)}, not {table['reset']!r}")
            values["reset"] = table["reset"]
        for name in ("capacitance", "voltage"):
            if name in values and values[name] <= 0:
                raise self.fail(f"sensor.{name}", "must be > 0")
        level = readout.level if readout.is_multibit else 1
        correlation = self.number(table, "dark_correlation_px", "sensor.", 1.5, minimum=0.0)
        return SensorParams(level=level, **values), correlation

    def background(self, table: dict) -> Background:
        self.check_keys(table, {"panorama", "gain", "center", "velocity", "zoom", "zoom_rate"}, "background.")
        panorama = table.get("panorama", "city")
        if not isinstance(panorama, str):
            raise self.fail("background.panorama", "must be a bundled panorama name or a path")
        return Background(
            panorama=self.panorama(panorama, "background.panorama"),
            gain=self.number(table, "gain", "background.", 1.0, minimum=0.0),
            center=self.vector(table, "center", "background.", (512.0, 256.0), 2),
            velocity=self.vector(table, "velocity", "background.", (0.0, 0.0), 2),
            zoom=self.zoom(table),
            zoom_rate=self.number(table, "zoom_rate", "background.", 0.0),
        )

    def scene_object(self, table: dict, index: int) -> SceneObject:
        prefix = f"objects[{index}]."
        self.check_keys(table, {f.name for f in fields(SceneObject)}, prefix)
        shape = table.get("shape", "rect")
        if shape not in SHAPES:
            raise self.fail(prefix + "shape", f"must be one of {', '.join(SHAPES)}, not {shape!r}")
        texture = table.get("texture", "checker")
        if not isinstance(texture, str) or not (texture in TEXTURES or texture.startswith("panorama:")):
            raise self.fail(prefix + "texture", f"must be one of {', '.join(TEXTURES)} or 'panorama:NAME'")
        if texture.startswith("panorama:"):
            texture = "panorama:" + self.panorama(texture.removeprefix("panorama:"), prefix + "texture")
        size = self.vector(table, "size", prefix, (40.0, 30.0), 2)
        if min(size) <= 0:
            raise self.fail(prefix + "size", "must be positive")
        crop = self.vector(table, "crop", prefix, (0, 0, 1, 1), 4) if "crop" in table else None
        if crop is not None and (crop[2] <= 0 or crop[3] <= 0):
            raise self.fail(prefix + "crop", "width and height must be positive")
        grid = self.vector(table, "grid", prefix, (4, 3), 2, maximum=MAX_GRID)
        if min(grid) < 1 or any(g != int(g) for g in grid):
            raise self.fail(prefix + "grid", "must be two positive integers")
        return SceneObject(
            shape=shape, size=size, position=self.vector(table, "position", prefix, (0.0, 0.0), 2),
            velocity=self.vector(table, "velocity", prefix, (0.0, 0.0), 2),
            angle_deg=self.number(table, "angle_deg", prefix, 0.0),
            angular_velocity_deg=self.number(table, "angular_velocity_deg", prefix, 0.0),
            texture=texture, radiance=self.number(table, "radiance", prefix, 1.0, minimum=0.0),
            crop=crop, grid=(int(grid[0]), int(grid[1])),
        )

    def panorama(self, name: str, key: str) -> str:
        """A bundled panorama's name as it is, or an EXR file's path, relative to the scene file's folder (not to the
        folder the command runs in); an error naming the key when it is neither."""
        if (HDRI_DIR / f"{name}.exr").is_file():
            return name
        path = Path(name).expanduser()
        path = (path if path.is_absolute() else self.path.parent / path).resolve()
        if not path.is_file():
            raise self.fail(key, f"names no bundled panorama ({', '.join(bundled_panoramas())}) and no file ({path})")
        return str(path)

    def dark_region(self, table: dict, index: int) -> DarkRegion:
        prefix = f"dark_regions[{index}]."
        self.check_keys(table, {"rect", "attenuation", "softness"}, prefix)
        if "rect" not in table:
            raise self.fail(prefix + "rect", "is required ([x, y, w, h] in panorama pixels)")
        rect = self.vector(table, "rect", prefix, (0, 0, 0, 0), 4)
        if rect[2] <= 0 or rect[3] <= 0:
            raise self.fail(prefix + "rect", "width and height must be positive")
        attenuation = self.number(table, "attenuation", prefix, 1e-2, minimum=0.0)
        if attenuation > 1:
            raise self.fail(prefix + "attenuation", "must be <= 1")
        return DarkRegion(rect=rect, attenuation=attenuation,
                          softness=self.number(table, "softness", prefix, 4.0, minimum=0.0))

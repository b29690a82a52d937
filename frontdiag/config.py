"""Frontend parameters from a TOML file (``analyze --config FILE.toml``), validated by pydantic.

The file has a ``[camera]`` and a ``[lidar]`` table whose keys are the fields of
:class:`~frontdiag.camera.frontend.CameraParams` and :class:`~frontdiag.lidar.frontend.LidarParams`;
an unknown key or an out-of-range value is one line naming the file and the key (exit 2). The
command-line options (``--features``, ``--ratio``, ``--no-mutual``, ``--ransac-iters``,
``--lidar-backend``) are checked by the same models and win over the file. Every result
directory gets the effective parameters back as ``frontend.toml``, which ``--config`` reads, so a
run can be repeated with exactly its settings.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from frontdiag.errors import ConfigError


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CameraConfig(_Strict):
    """Camera frontend: ORB detection with grid bucketing, matching, RANSAC, keyframes."""

    n_features: int = Field(default=1000, ge=50, le=100_000, description="ORB feature budget per frame")
    n_levels: int = Field(default=8, ge=1, le=16, description="pyramid levels")
    scale_factor: float = Field(default=1.2, gt=1.0, le=2.0, description="pyramid scale step")
    fast_threshold: int = Field(default=20, ge=1, le=255, description="FAST threshold (grey levels)")
    fast_threshold_min: int = Field(default=7, ge=1, le=255,
                                    description="FAST threshold retried in empty grid cells")
    grid_cols: int = Field(default=8, ge=1, le=64, description="bucketing grid columns")
    grid_rows: int = Field(default=6, ge=1, le=64, description="bucketing grid rows")
    ratio: float = Field(default=0.8, gt=0.0, le=1.0, description="Lowe ratio threshold")
    mutual: bool = Field(default=True, description="mutual-consistency check in matching")
    ransac_confidence: float = Field(default=0.999, gt=0.0, lt=1.0, description="RANSAC confidence p")
    sigma_px: float = Field(default=1.0, gt=0.0, le=20.0, description="keypoint noise (px); sets the "
                            "inlier thresholds 1.96 sigma (E) and 2.45 sigma (H)")
    ransac_max_iters: int = Field(default=1000, ge=1, le=1_000_000, description="RANSAC iteration cap")
    min_correspondences: int = Field(default=15, ge=5, le=10_000,
                                     description="fewer correspondences: tracking lost")
    kf_max_frames: int = Field(default=20, ge=1, le=10_000, description="keyframe after this many frames")
    kf_min_tracked_share: float = Field(default=0.9, gt=0.0, le=1.0,
                                        description="keyframe when the tracked share falls below")
    kf_parallax_deg: float = Field(default=2.29, gt=0.0, le=90.0,
                                   description="keyframe when the median parallax reaches")
    relink_tracks: bool = True
    two_interval_px: float = Field(default=4.9, ge=0.0, le=1000.0,
                                   description="read H/E two keyframes back when an interval "
                                               "spans fewer pixels of parallax than this")
    rot_fit_he: float = Field(default=0.9, ge=0.0, le=1.0,
                              description="take the rotation-only fit where H/E is above this "
                                          "(lowered to the rules' he_degenerate)")
    rot_fit_parallax_deg: float = Field(default=0.3, ge=0.0, le=90.0,
                                        description="... with at least this parallax (deg)")
    rot_fit_turn_px: float = Field(default=10.0, ge=0.0, le=100000.0,
                                   description="... and on keyframe intervals whose rotation "
                                               "moves the image this much (px), whatever H/E "
                                               "(lowered to the rules' rot_fit_turn_px)")
    rot_span_s: float = Field(default=0.33, ge=0.0, le=60.0,
                              description="read the motion over at least this long (s) where a "
                                          "keyframe interval is shorter and could read as "
                                          "rotation or standing still; 0: never")
    rot_span_focal_px: float = Field(default=495.0, ge=0.0, le=100000.0,
                                     description="below this focal length (px) the span is "
                                                 "longer, rot_span_s x rot_span_focal_px / fx, "
                                                 "so slow motion rises above pixel noise at "
                                                 "any resolution; 0: never longer")
    seed: int = Field(default=0, ge=0, description="RANSAC seed")

    @model_validator(mode="after")
    def _thresholds(self) -> CameraConfig:
        if self.fast_threshold_min > self.fast_threshold:
            raise ValueError("fast_threshold_min must not exceed fast_threshold")
        return self


class LidarConfig(_Strict):
    """LiDAR frontend: range filter, voxel grid, point-to-plane registration, local map."""

    voxel_size_m: float = Field(default=0.5, gt=0.0, le=10.0, description="voxel grid (3D scans)")
    planar_voxel_size_m: float = Field(default=0.05, gt=0.0, le=5.0, description="voxel grid (2D scans)")
    min_range_m: float = Field(default=0.3, ge=0.0, description="drop returns closer than this")
    max_range_m: float = Field(default=100.0, gt=0.0, description="drop returns further than this")
    map_keyframes: int = Field(default=20, ge=1, le=1000, description="keyframes in the local map")
    keyframe_dist_m: float = Field(default=1.0, gt=0.0)
    keyframe_angle_deg: float = Field(default=10.0, gt=0.0, le=180.0)
    max_iterations: int = Field(default=30, ge=1, le=1000, description="registration iterations")
    initial_threshold_m: float = Field(default=2.0, gt=0.0, description="correspondence threshold "
                                       "before any motion is known")
    min_motion_m: float = Field(default=0.1, ge=0.0)
    normal_neighbors: int = Field(default=10, ge=3, le=200)
    min_points: int = Field(default=100, ge=6)
    min_points_planar: int = Field(default=20, ge=3)
    min_fitness: float = Field(default=0.3, ge=0.0, le=1.0)
    backend: Literal["auto", "small_gicp", "open3d"] = "auto"
    num_threads: int = Field(default=1, ge=1, le=256)

    @model_validator(mode="after")
    def _ranges(self) -> LidarConfig:
        if self.min_range_m >= self.max_range_m:
            raise ValueError("min_range_m must be below max_range_m")
        return self


class FrontendConfig(_Strict):
    camera: CameraConfig = Field(default_factory=CameraConfig)
    lidar: LidarConfig = Field(default_factory=LidarConfig)

    def camera_params(self) -> Any:
        from frontdiag.camera.frontend import CameraParams

        return CameraParams(**self.camera.model_dump())

    def lidar_params(self) -> Any:
        from frontdiag.lidar.frontend import LidarParams

        return LidarParams(**self.lidar.model_dump())


def _problem(exc: ValidationError) -> str:
    e = exc.errors()[0]
    loc = ".".join(str(x) for x in e["loc"])
    return f"{loc}: {e['msg']}" if loc else e["msg"]


def load_config(path: Path | None, overrides: dict[str, dict[str, Any]] | None = None
                ) -> FrontendConfig:
    """Read ``path`` (or the defaults), apply the command line's ``overrides`` on top, and
    validate the whole with the models above."""
    data: dict[str, Any] = {}
    where = "command-line options"
    if path is not None:
        path = Path(path)
        where = str(path)
        try:
            with path.open("rb") as fh:
                data = tomllib.load(fh)
        except FileNotFoundError:
            raise ConfigError(f"--config {path}: no such file") from None
        except OSError as exc:
            raise ConfigError(f"--config {path}: cannot read it ({exc.strerror})") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"--config {path}: not valid TOML ({exc})") from None
    for section, values in (overrides or {}).items():
        data.setdefault(section, {})
        if not isinstance(data[section], dict):
            break
        data[section].update({k: v for k, v in values.items() if v is not None})
    try:
        return FrontendConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{where}: {_problem(exc)}",
                          hint="the keys and their ranges: docs/config.md") from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(v)


def dump_toml(params: dict[str, Any]) -> str:
    """``{"camera": {...}, "lidar": {...}}`` as the TOML that ``--config`` reads."""
    lines = ["# effective frontend parameters of this run; rerun with `frontdiag analyze LOG "
             "--config frontend.toml`"]
    for section in ("camera", "lidar"):
        values = params.get(section)
        if not values:
            continue
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


def params_dict(obj: Any) -> dict[str, Any]:
    """A CameraParams/LidarParams dataclass as a dict of its fields."""
    return {f.name: getattr(obj, f.name) for f in fields(obj)} if obj is not None else {}


__all__ = ["CameraConfig", "FrontendConfig", "LidarConfig", "asdict", "dump_toml", "load_config"]

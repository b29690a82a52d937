"""Camera intrinsics from a CameraInfo message, ``--intrinsics fx,fy,cx,cy`` or a ROS YAML file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from frontdiag.errors import ConfigError
from frontdiag.records import Intrinsics

CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
KNOWN_MODELS = ("plumb_bob", "rational_polynomial", "equidistant", "fisheye", "none", "")

HOW_TO_PASS_K = ("pass intrinsics with --intrinsics fx,fy,cx,cy or --camera-info camera.yaml "
                 "(a ROS camera_info YAML)")


def _field(msg: Any, name: str) -> Any:
    """CameraInfo fields are ``K``/``D`` in ROS 1 and ``k``/``d`` in ROS 2."""
    if hasattr(msg, name.lower()):
        return getattr(msg, name.lower())
    return getattr(msg, name.upper())


def from_camera_info(msg: Any, topic: str) -> Intrinsics | None:
    """Intrinsics from a CameraInfo message; None when K is unset (all zeros)."""
    K = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        return None
    D = np.asarray(_field(msg, "d"), dtype=np.float64).reshape(-1)
    model = str(msg.distortion_model).strip().lower()
    return Intrinsics(K=K, D=D, model=_model(model, D), width=int(msg.width),
                      height=int(msg.height), source=f"CameraInfo on {topic}")


def _model(model: str, D: np.ndarray) -> str:
    if model == "fisheye":
        return "equidistant"
    if model in ("", "none") and not np.any(D):
        return "none"
    if model not in KNOWN_MODELS:
        raise ConfigError(f"distortion model {model!r} is not supported "
                          "(plumb_bob, rational_polynomial, equidistant)")
    return model or "plumb_bob"


def parse_intrinsics(text: str) -> Intrinsics:
    """``fx,fy,cx,cy`` (pixels) from the command line."""
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        vals = []
    if len(vals) != 4 or vals[0] <= 0 or vals[1] <= 0:
        raise ConfigError(f"--intrinsics {text!r}: expected four numbers fx,fy,cx,cy with "
                          "fx, fy > 0, e.g. --intrinsics 525,525,319.5,239.5")
    fx, fy, cx, cy = vals
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return Intrinsics(K=K, model="none", source="--intrinsics")


def load_camera_info_yaml(path: Path | str) -> Intrinsics:
    """A ROS ``camera_info`` YAML (camera_calibration / camera_info_manager format)."""
    import yaml  # PyYAML comes with rosbags

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"--camera-info {path}: no such file") from exc
    except Exception as exc:
        raise ConfigError(f"--camera-info {path}: not valid YAML ({exc})") from exc
    if not isinstance(doc, dict) or "camera_matrix" not in doc:
        raise ConfigError(f"--camera-info {path}: missing field camera_matrix "
                          "(expected a ROS camera_info YAML)")
    try:
        K = np.asarray(doc["camera_matrix"]["data"], dtype=np.float64).reshape(3, 3)
        D = np.asarray((doc.get("distortion_coefficients") or {}).get("data", []),
                       dtype=np.float64).reshape(-1)
    except Exception as exc:
        raise ConfigError(f"--camera-info {path}: field camera_matrix.data must hold 9 "
                          f"numbers ({exc})") from exc
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ConfigError(f"--camera-info {path}: camera_matrix has fx or fy <= 0")
    model = str(doc.get("distortion_model", "plumb_bob")).strip().lower()
    return Intrinsics(K=K, D=D, model=_model(model, D), width=int(doc.get("image_width", 0)),
                      height=int(doc.get("image_height", 0)), source=f"--camera-info {path}")


def camera_info_topic_for(image_topic: str, info_topics: list[str]) -> str | None:
    """The CameraInfo topic that belongs to an image topic (same namespace), if any."""
    if not info_topics:
        return None
    parts = image_topic.rstrip("/").split("/")
    # /cam/image_raw -> /cam ; /cam/image_raw/compressed -> /cam
    for depth in range(len(parts) - 1, 0, -1):
        ns = "/".join(parts[:depth])
        cand = f"{ns}/camera_info"
        if cand in info_topics:
            return cand
    return info_topics[0] if len(info_topics) == 1 else None

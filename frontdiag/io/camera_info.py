"""Camera intrinsics from a CameraInfo message, ``--intrinsics fx,fy,cx,cy`` or a ROS YAML file."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from frontdiag.errors import ConfigError
from frontdiag.records import Intrinsics

CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
CAMERA_INFO_TYPES = (CAMERA_INFO_TYPE, "foxglove.CameraCalibration",
                     "foxglove_msgs/msg/CameraCalibration")
KNOWN_MODELS = ("plumb_bob", "rational_polynomial", "equidistant", "fisheye", "none", "")

HOW_TO_PASS_K = ("pass intrinsics with --intrinsics fx,fy,cx,cy or --camera-info camera.yaml "
                 "(a ROS camera_info YAML)")


def _field(msg: Any, name: str) -> Any:
    """CameraInfo fields are ``K``/``D`` in ROS 1 and ``k``/``d`` in ROS 2."""
    if hasattr(msg, name.lower()):
        return getattr(msg, name.lower())
    return getattr(msg, name.upper())


def is_rectified_topic(topic: str) -> bool:
    """Whether an image topic's name says its images are rectified: image_pipeline's
    ``image_rect`` / ``image_rect_color``, RealSense's ``image_rect_raw``, ZED's
    ``image_rect_color`` / ``image_rect_gray`` (also under ``/compressed``)."""
    return any(part.startswith("image_rect") for part in topic.split("/"))


def from_camera_info(msg: Any, topic: str, notes: list[str] | None = None,
                     rectified: bool = False) -> Intrinsics | None:
    """Intrinsics from a CameraInfo message for the images it describes: those of
    :func:`_full_resolution`, moved to the message's region of interest and binning.

    CameraInfo holds the calibration at full sensor resolution; ``roi`` (x_offset, y_offset,
    width, height, in full-resolution pixels; all zero for the full image) and ``binning_x`` /
    ``binning_y`` (0 or 1 for none) say which part of the sensor the images show and how many
    sensor pixels each image pixel sums (sensor_msgs/CameraInfo). A region of interest moves the
    principal point by its offset; binning by b maps a full-resolution pixel centre x to
    (x + 0.5) / b - 0.5 and divides the focal length by b. Distortion acts on normalised
    coordinates and stays as it is.
    """
    intr = _full_resolution(msg, topic, notes, rectified)
    if intr is None:
        return None
    roi = getattr(msg, "roi", None)
    ox, oy = int(getattr(roi, "x_offset", 0) or 0), int(getattr(roi, "y_offset", 0) or 0)
    rw, rh = int(getattr(roi, "width", 0) or 0), int(getattr(roi, "height", 0) or 0)
    bx = max(int(getattr(msg, "binning_x", 0) or 0), 1)
    by = max(int(getattr(msg, "binning_y", 0) or 0), 1)
    use_roi = rw > 0 and rh > 0 and (ox, oy, rw, rh) != (0, 0, intr.width, intr.height)
    if not use_roi and bx == 1 and by == 1:
        return intr
    K = np.array(intr.K, dtype=np.float64)
    w, h = (rw, rh) if use_roi else (intr.width, intr.height)
    what = []
    if use_roi:
        K[0, 2] -= ox
        K[1, 2] -= oy
        what.append(f"region of interest {rw}x{rh} at ({ox}, {oy})")
    if bx > 1 or by > 1:
        K = scaled_K(K, 1.0 / bx, 1.0 / by)
        w, h = w // bx, h // by
        what.append(f"binning {bx}x{by}")
    if notes is not None:
        notes.append(f"{intr.source}: K moved to its {' and '.join(what)} ({w}x{h} images)")
    return replace(intr, K=K, width=w, height=h)


def scaled_K(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """K for the same view resampled by ``sx`` across and ``sy`` down (a resize, or binning by
    1/s). A pixel centre x maps to (x + 0.5) s - 0.5, so fx' = s fx and cx' = (cx + 0.5) s - 0.5;
    distortion acts on normalised coordinates and is not changed."""
    K = np.array(K, dtype=np.float64)
    K[0, 0], K[0, 1], K[1, 1] = K[0, 0] * sx, K[0, 1] * sx, K[1, 1] * sy
    K[0, 2], K[1, 2] = (K[0, 2] + 0.5) * sx - 0.5, (K[1, 2] + 0.5) * sy - 0.5
    return K


def _full_resolution(msg: Any, topic: str, notes: list[str] | None = None,
                     rectified: bool = False) -> Intrinsics | None:
    """Intrinsics from a CameraInfo message; None when K is unset (all zeros).

    ``rectified``: the images are already rectified (:func:`is_rectified_topic`). CameraInfo's
    K and D describe the raw images; the rectified ones are described by the projection
    matrix P, whose left 3x3 is their intrinsic matrix, with no distortion (REP 104 /
    sensor_msgs/CameraInfo). Undistorting rectified images with D would bend them again. P is
    used where it is set (fx, fy > 0), with a note; otherwise K and D, with a note.

    Raises ConfigError naming the topic and field for a calibration no camera model can use
    (NaN or infinite values, a distortion vector of the wrong length, an unknown model with
    non-zero coefficients).
    """
    where = f"CameraInfo on {topic}"
    if rectified:
        try:
            P = np.asarray(_field(msg, "p"), dtype=np.float64).reshape(3, 4)
        except (ValueError, TypeError):
            P = np.zeros((3, 4))
        if np.all(np.isfinite(P)) and P[0, 0] > 0 and P[1, 1] > 0:
            if notes is not None:
                notes.append(f"{where}: the images are rectified, so P's intrinsics are used "
                             "(no distortion), not K and D, which describe the raw images")
            return checked(Intrinsics(K=P[:, :3].copy(), D=np.zeros(0), model="none",
                                      width=int(msg.width), height=int(msg.height),
                                      source=f"{where} (P)"), notes)
        if notes is not None:
            notes.append(f"{where}: the images are rectified but P is unset; K and D are used")
    try:
        K = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3)
        D = np.asarray(_field(msg, "d"), dtype=np.float64).reshape(-1)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: field K must hold 9 numbers ({_first_line(exc)})",
                          hint=f"{HOW_TO_PASS_K} to override it") from exc
    if not np.isnan(K).any() and (K[0, 0] <= 0 or K[1, 1] <= 0):
        return None
    return checked(Intrinsics(K=K, D=D, model=str(msg.distortion_model), width=int(msg.width),
                              height=int(msg.height), source=where), notes)


# Coefficient counts OpenCV's models take (ROS writes 5 for plumb_bob, 8 for rational_polynomial).
D_COUNTS = {"plumb_bob": (4, 5, 8, 12, 14), "rational_polynomial": (4, 5, 8, 12, 14),
            "equidistant": (4,)}


def checked(intr: Intrinsics, notes: list[str] | None = None) -> Intrinsics:
    """Validate and normalise a calibration, or raise ConfigError naming its source and field.

    * K must be finite with fx, fy > 0; D must be finite.
    * ``fisheye`` is ``equidistant``; an empty or all-zero D means no distortion, whatever the
      model is called (RealSense writes "Brown Conrady" with zeros): model ``none``, with a note
      when the name is not one of the ROS models.
    * A D longer than the model takes is accepted when the extra coefficients are zero.
    """
    src = intr.source
    hint = f"{HOW_TO_PASS_K} to override it" if not src.startswith("--") else None
    K = np.asarray(intr.K, dtype=np.float64)
    D = np.asarray(intr.D, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(K)):
        raise ConfigError(f"{src}: K holds NaN or infinite values", hint=hint)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ConfigError(f"{src}: K has fx or fy <= 0", hint=hint)
    if not np.all(np.isfinite(D)):
        raise ConfigError(f"{src}: D holds NaN or infinite values", hint=hint)
    model = intr.model.strip().lower()
    model = "equidistant" if model == "fisheye" else model
    if not np.any(D):
        if model not in KNOWN_MODELS and notes is not None:
            notes.append(f"{src}: distortion model {intr.model!r} is not a ROS model; its "
                         "coefficients are all zero, so no distortion is applied")
        return replace(intr, K=K, D=np.zeros(0), model="none")
    model = model or "plumb_bob"
    if model not in D_COUNTS:
        raise ConfigError(f"{src}: distortion model {intr.model!r} is not supported "
                          "(plumb_bob, rational_polynomial, equidistant)", hint=hint)
    counts = D_COUNTS[model]
    if D.size not in counts:
        last = int(np.flatnonzero(D)[-1]) + 1
        fits = [n for n in counts if last <= n <= D.size]
        if not fits:
            raise ConfigError(f"{src}: distortion model {model} takes "
                              f"{' or '.join(map(str, counts))} coefficients in D, got {D.size}",
                              hint=hint)
        D = D[:fits[-1]]
    return replace(intr, K=K, D=D, model=model)


def parse_intrinsics(text: str) -> Intrinsics:
    """``fx,fy,cx,cy`` (pixels) from the command line."""
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        vals = []
    if len(vals) != 4 or not all(np.isfinite(vals)) or vals[0] <= 0 or vals[1] <= 0:
        raise ConfigError(f"--intrinsics {text!r}: expected four finite numbers fx,fy,cx,cy "
                          "with fx, fy > 0, e.g. --intrinsics 525,525,319.5,239.5")
    fx, fy, cx, cy = vals
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return Intrinsics(K=K, model="none", source="--intrinsics")


def load_camera_info_yaml(path: Path | str, notes: list[str] | None = None) -> Intrinsics:
    """A ROS ``camera_info`` YAML (camera_calibration / camera_info_manager format)."""
    import yaml  # PyYAML comes with rosbags

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"--camera-info {path}: no such file") from exc
    except Exception as exc:
        raise ConfigError(f"--camera-info {path}: not valid YAML ({_first_line(exc)})") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("camera_matrix"), dict):
        raise ConfigError(f"--camera-info {path}: missing field camera_matrix "
                          "(expected a ROS camera_info YAML)")
    try:
        K = np.asarray(doc["camera_matrix"].get("data"), dtype=np.float64).reshape(3, 3)
        dist = doc.get("distortion_coefficients") or {}
        D = np.asarray(dist.get("data", []) if isinstance(dist, dict) else [],
                       dtype=np.float64).reshape(-1)
        width, height = int(doc.get("image_width", 0) or 0), int(doc.get("image_height", 0) or 0)
    except Exception as exc:
        raise ConfigError(f"--camera-info {path}: field camera_matrix.data must hold 9 "
                          f"numbers ({_first_line(exc)})") from exc
    model = str(doc.get("distortion_model", "plumb_bob"))
    return checked(Intrinsics(K=K, D=D, model=model, width=width, height=height,
                              source=f"--camera-info {path}"), notes)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else type(exc).__name__


def camera_info_topic_for(image_topic: str, info_topics: list[str]) -> str | None:
    """The CameraInfo topic that belongs to an image topic (same namespace), if any.

    ROS drivers put it beside the image (``/cam/image_raw`` -> ``/cam/camera_info``); the
    RealSense SDK's bag layout keeps it one level down (``.../Color_0/image/data`` ->
    ``.../Color_0/info/camera_info``); Foxglove's ``CameraCalibration`` is usually published as
    ``/cam/calibration``.
    """
    if not info_topics:
        return None
    parts = image_topic.rstrip("/").split("/")
    # /cam/image_raw -> /cam ; /cam/image_raw/compressed -> /cam
    for depth in range(len(parts) - 1, 0, -1):
        ns = "/".join(parts[:depth])
        for cand in (f"{ns}/camera_info", f"{ns}/info/camera_info", f"{ns}/calibration",
                     f"{ns}/camera_calibration"):
            if cand in info_topics:
                return cand
    return info_topics[0] if len(info_topics) == 1 else None


def fit_to_images(intr: Intrinsics, size: tuple[int, int] | None,
                  notes: list[str]) -> Intrinsics:
    """The calibration for images of ``size``: K scaled where the images are the calibrated
    view resized (or binned), the same aspect ratio within 1 %; as it is, with a note, where
    they are another view (a crop or region of interest), which K does not describe.

    A calibration describes the image size it was made at; a resize node or binning that
    passes the CameraInfo on unchanged leaves K for the full view, and the principal point then
    lies far from the images' centre, which biases every E, parallax and rotation reading.
    The scaling is :func:`scaled_K`, the one binning uses.
    """
    if size is None or (size[0], size[1]) == (intr.width, intr.height):
        return intr
    if intr.width <= 0 or intr.height <= 0:  # a calibration that gives no size: taken as is
        return intr
    w, h = size
    sx, sy = w / intr.width, h / intr.height
    if abs(sx - sy) > 0.01 * max(sx, sy):
        what = "a crop or region of interest"
        if (w, h) in ((2 * intr.width, intr.height), (intr.width, 2 * intr.height)):
            # ZED and other stereo cameras publish the pair side by side (or over-under) on
            # one topic, with the CameraInfo of one eye
            what = ("twice the calibration's width or height: a stereo pair side by side in one "
                    "picture, which no single-camera geometry describes; analyse one eye's topic "
                    "with --camera-topic")
        notes.append(f"{intr.source} is for {intr.width}x{intr.height} images but the camera's "
                     f"are {w}x{h}, another aspect ratio ({what}): K is used as it is and the "
                     f"geometry readings are suspect; {HOW_TO_PASS_K} for these images")
        return intr
    K = scaled_K(intr.K, sx, sy)
    notes.append(f"{intr.source} is for {intr.width}x{intr.height} images, the camera's are "
                 f"{w}x{h}: K scaled by {sx:.4g} (the same view resized)")
    return replace(intr, K=K, width=w, height=h,
                   source=f"{intr.source}, scaled to {w}x{h}")


class CalibrationsBySize:
    """The recording's own CameraInfo for images of a given size, looked up when the camera's
    image size changes mid-recording (a driver reconfigured to another resolution or binning
    publishes the calibration of its new mode).

    ``calibration(w, h)`` is the first usable CameraInfo message on ``topic`` (in recording
    order) that describes w x h images (after its region of interest and binning), or None.
    A function of the recording and the size alone, so every window of a split run finds the
    same one. The topic is read, from the recording opened anew, the first time each size is
    asked for, and only then: a camera that keeps its size costs nothing.
    """

    def __init__(self, path: Path, topic: str, rectified: bool = False,
                 limit: int | None = None, downscale: int = 1) -> None:
        self.path = Path(path)
        self.topic = topic
        self.rectified = rectified
        self.limit = limit  # messages read at most (None: the whole topic)
        self.downscale = downscale  # the pictures are shrunk by it (analyze --downscale)
        self._found: dict[tuple[int, int], tuple[Intrinsics, int] | None] = {}

    def calibration(self, w: int, h: int) -> tuple[Intrinsics, int] | None:
        """(calibration, message number from 1) of the first usable CameraInfo for w x h
        pictures: made for them, or for the images they were shrunk from (then scaled)."""
        if (w, h) not in self._found:
            found = self._scan(w, h)
            if found is not None and (found[0].width, found[0].height) != (w, h):
                found = (fit_to_images(found[0], (w, h), []), found[1])
            self._found[(w, h)] = found
        return self._found[(w, h)]

    def _scan(self, w: int, h: int) -> tuple[Intrinsics, int] | None:
        from frontdiag.errors import FrontdiagError
        from frontdiag.io.images import shrunk_size
        from frontdiag.io.readers import open_recording

        try:
            with open_recording(self.path) as rec:
                for i, raw in enumerate(rec.messages([self.topic])):
                    if self.limit is not None and i >= self.limit:
                        break
                    try:
                        intr = from_camera_info(rec.deserialize(raw), self.topic,
                                                rectified=self.rectified)
                    except Exception:  # unusable: the next one may be
                        continue
                    if intr is not None and intr.width > 0 and intr.height > 0 and \
                            shrunk_size(intr.width, intr.height, self.downscale) == (w, h):
                        return intr, i + 1
        except (FrontdiagError, OSError):
            return None
        return None

"""Convert ``sensor_msgs/Image`` and ``CompressedImage`` to 8-bit grey, in one place.

Every frame the frontend sees passes through :func:`to_gray`. Errors name the topic and the
field at fault and are raised as :class:`~frontdiag.errors.DecodeError`; the caller skips and
counts a bad single message.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import cv2
import numpy as np

from frontdiag.errors import DecodeError
from frontdiag.io import foxglove

# ffmpeg_image_transport's packets (ROS 1 and 2): one encoded picture a message, the encoder
# named in ``encoding`` (libx264, h264_nvenc, hevc_vaapi, ...)
FFMPEG_PACKET_TYPES = ("ffmpeg_image_transport_msgs/msg/FFMPEGPacket",)
VIDEO_TYPES = (*foxglove.VIDEO_TYPES, *FFMPEG_PACKET_TYPES)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage",
               *foxglove.IMAGE_TYPES, *FFMPEG_PACKET_TYPES)


def is_video(msgtype: str) -> bool:
    """Whether a message type carries video, whose pictures depend on earlier messages (see
    also :func:`is_video_topic`: a CompressedImage topic can carry video too)."""
    return msgtype in VIDEO_TYPES


def is_video_message(msg: Any, msgtype: str) -> bool:
    """A video message type, or a CompressedImage whose ``format`` names a video codec (FFmpeg
    based image_transport plugins publish H.264 that way)."""
    if is_video(msgtype):
        return True
    return (foxglove.ros_type(msgtype).endswith("CompressedImage")
            and str(getattr(msg, "format", "")).strip().lower() in VIDEO_CODECS)


def is_video_topic(rec: Any, topic: str, msgtype: str) -> bool:
    """Whether a camera topic carries video: by its type, or for a CompressedImage topic by
    its first message's format."""
    if is_video(msgtype):
        return True
    if not msgtype.endswith("CompressedImage"):
        return False
    for raw in rec.messages([topic]):
        try:
            return is_video_message(rec.deserialize(raw), raw.msgtype)
        except Exception:  # the pass reports undecodable messages
            return False
    return False


def video_format(msg: Any, msgtype: str) -> str:
    """The codec of a video message: Foxglove's ``format`` (h264, h265, vp9, av1), or the one
    an ffmpeg_image_transport packet's encoder name says (``h264_nvenc`` -> h264)."""
    if msgtype not in FFMPEG_PACKET_TYPES:
        return str(msg.format).strip().lower()
    enc = str(msg.encoding).strip().lower()
    for key, fmt in (("264", "h264"), ("265", "h265"), ("hevc", "h265"), ("av1", "av1"),
                     ("vp9", "vp9")):
        if key in enc:
            return fmt
    return enc

# ROS encoding -> (channels, bytes per channel, cv2 conversion to grey or None)
_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    "mono8": (1, 1, None),
    "8uc1": (1, 1, None),
    "mono16": (1, 2, None),
    "16uc1": (1, 2, None),
    "rgb8": (3, 1, cv2.COLOR_RGB2GRAY),
    "bgr8": (3, 1, cv2.COLOR_BGR2GRAY),
    "8uc3": (3, 1, cv2.COLOR_BGR2GRAY),
    "rgba8": (4, 1, cv2.COLOR_RGBA2GRAY),
    "bgra8": (4, 1, cv2.COLOR_BGRA2GRAY),
    "8uc4": (4, 1, cv2.COLOR_BGRA2GRAY),
    # 16 bits a channel (machine-vision cameras' 10-12 bit colour): grey at 16 bits, then the
    # run's fixed 16-to-8 mapping, as mono16
    "rgb16": (3, 2, cv2.COLOR_RGB2GRAY),
    "bgr16": (3, 2, cv2.COLOR_BGR2GRAY),
    "16uc3": (3, 2, cv2.COLOR_BGR2GRAY),
    "rgba16": (4, 2, cv2.COLOR_RGBA2GRAY),
    "bgra16": (4, 2, cv2.COLOR_BGRA2GRAY),
    "16uc4": (4, 2, cv2.COLOR_BGRA2GRAY),
    # ROS names the pattern of the top-left 2x2 block; OpenCV names the second row's
    # second and third pixels, hence the shift (the same mapping cv_bridge uses).
    "bayer_rggb8": (1, 1, cv2.COLOR_BayerBG2GRAY),
    "bayer_bggr8": (1, 1, cv2.COLOR_BayerRG2GRAY),
    "bayer_gbrg8": (1, 1, cv2.COLOR_BayerGR2GRAY),
    "bayer_grbg8": (1, 1, cv2.COLOR_BayerGB2GRAY),
    "bayer_rggb16": (1, 2, cv2.COLOR_BayerBG2GRAY),
    "bayer_bggr16": (1, 2, cv2.COLOR_BayerRG2GRAY),
    "bayer_gbrg16": (1, 2, cv2.COLOR_BayerGR2GRAY),
    "bayer_grbg16": (1, 2, cv2.COLOR_BayerGB2GRAY),
    # packed 4:2:2 (two bytes a pixel): "yuv422" is UYVY (ROS 1 and 2), "yuv422_yuy2" YUYV
    # (ROS 2), and newer ROS 2 releases name them "uyvy" and "yuyv"; grey is each pixel's luma
    "yuv422": (2, 1, cv2.COLOR_YUV2GRAY_UYVY),
    "uyvy": (2, 1, cv2.COLOR_YUV2GRAY_UYVY),
    "yuv422_yuy2": (2, 1, cv2.COLOR_YUV2GRAY_YUY2),
    "yuyv": (2, 1, cv2.COLOR_YUV2GRAY_YUY2),
    # semi-planar 4:2:0 (Jetson and phone camera pipelines): a full-size luma plane of
    # ``height`` rows of ``step`` bytes, then one of interleaved chroma at half height, which
    # grey does not need (``_YUV420SP``)
    "nv12": (1, 1, None),
    "nv21": (1, 1, None),
}
_YUV420SP = ("nv12", "nv21")
"""Encodings whose data holds 1.5 x height rows: the luma plane, then the chroma."""
SUPPORTED_ENCODINGS: tuple[str, ...] = tuple(k for k in _ENCODINGS if not k[0].isdigit())


@dataclass
class GrayConverter:
    """Stateful for 16-bit pictures, whose mapping to 8 bits is fixed from the first frame so
    that frame means stay comparable across the run (a per-frame stretch would hide exposure
    steps; :meth:`_mono16_to_8`); and for video, whose pictures depend on the ones before them
    (:class:`VideoDecoder`)."""

    topic: str
    mono16_map: Mono16Mapping | None = None
    """How 16-bit pictures are mapped to 8 bits, fixed from the first one (None before it)."""
    video: VideoDecoder | None = None
    downscale: int = 1
    """Pictures are shrunk by this integer factor (``analyze --downscale``), box-averaged."""

    @property
    def mono16(self) -> dict[str, Any] | None:
        """The 16-bit mapping in use (for the manifest, from which :meth:`mapped` rebuilds it),
        or None before any 16-bit picture."""
        return None if self.mono16_map is None else self.mono16_map.as_dict()

    @classmethod
    def mapped(cls, topic: str, mono16: Mapping[str, Any] | None,
               downscale: int = 1) -> GrayConverter:
        """A converter that maps 16-bit pictures as a run did (its ``mono16``) and shrinks them
        as it did, so a picture re-read on its own is the one the frontend saw."""
        return cls(topic, mono16_map=Mono16Mapping.from_dict(mono16) if mono16 else None,
                   downscale=downscale)

    def __call__(self, msg: Any, msgtype: str) -> tuple[np.ndarray, str]:
        gray, encoding = self._grey(msg, msgtype)
        if self.downscale > 1:
            gray = shrink(gray, self.downscale)
        return gray, encoding

    def _grey(self, msg: Any, msgtype: str) -> tuple[np.ndarray, str]:
        msgtype = foxglove.ros_type(msgtype)
        if is_video_message(msg, msgtype):
            fmt = video_format(msg, msgtype)
            # a stream restarted with another codec (or a first message naming the wrong one)
            # is decoded anew from the new codec's first keyframe (or at once, where keyframes
            # cannot be told); until then its messages are skipped with the reason
            if self.video is None or (fmt != self.video.fmt and fmt in VIDEO_CODECS
                                      and is_keyframe(msg.data, fmt) is not False):
                self.video = VideoDecoder(self.topic, fmt)
            return self.video(msg.data, fmt), f"video/{fmt or '?'}"
        if msgtype.endswith("CompressedImage"):
            return self._compressed(msg), f"compressed/{str(msg.format).strip() or '?'}"
        return self._raw(msg), str(msg.encoding)

    def _compressed(self, msg: Any) -> np.ndarray:
        buf = np.asarray(msg.data, dtype=np.uint8)
        if buf.size == 0:
            raise DecodeError(self.topic, "data", "empty compressed image")
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise DecodeError(self.topic, "data",
                              f"cannot decode compressed image (format {msg.format!r})")
        if img.dtype == np.uint16:
            img = self._mono16_to_8(img.astype(np.uint16))
        if img.ndim == 3:
            code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            img = cv2.cvtColor(img, code)
        return img

    def _raw(self, msg: Any) -> np.ndarray:
        enc = str(msg.encoding).strip().lower()
        spec = _ENCODINGS.get(enc)
        if spec is None:
            raise DecodeError(self.topic, "encoding",
                              f"unsupported encoding {msg.encoding!r} (supported: "
                              f"{', '.join(SUPPORTED_ENCODINGS)})")
        channels, depth, code = spec
        h, w, step = int(msg.height), int(msg.width), int(msg.step)
        if h <= 0 or w <= 0:
            raise DecodeError(self.topic, "height/width", f"image is {w}x{h}")
        row_bytes = w * channels * depth
        if step < row_bytes:
            raise DecodeError(self.topic, "step",
                              f"step {step} is smaller than width*channels*bytes = {row_bytes} "
                              f"for {w}x{h} {enc}")
        data = np.asarray(msg.data, dtype=np.uint8)
        need, what = step * h, "step*height"
        if enc in _YUV420SP:  # the chroma plane's rows count too: a cut message is damaged
            need, what = step * (h + (h + 1) // 2), "step*height*1.5 (luma, then chroma)"
        if data.size < need:
            raise DecodeError(self.topic, "data",
                              f"{data.size} bytes, expected {what} = {need} for "
                              f"{w}x{h} {enc}")
        rows = data[: step * h].reshape(h, step)[:, :row_bytes]
        if depth == 2:
            dt = np.dtype(">u2") if int(msg.is_bigendian) else np.dtype("<u2")
            img16: np.ndarray = np.ascontiguousarray(rows).view(dt).astype(np.uint16)
            img16 = img16.reshape(h, w, channels) if channels > 1 else img16.reshape(h, w)
            if code is not None:  # grey at 16 bits (OpenCV converts and demosaics 16U)
                img16 = cv2.cvtColor(img16, code)
            return self._mono16_to_8(img16)
        img: np.ndarray = rows.reshape(h, w, channels) if channels > 1 else rows
        img = np.ascontiguousarray(img)
        if code is not None:
            img = cv2.cvtColor(img, code)
        return img

    def _mono16_to_8(self, img16: np.ndarray) -> np.ndarray:
        """8 bits from 16, by a mapping fixed from the first frame (:func:`mono16_mapping`)."""
        if self.mono16_map is None:
            self.mono16_map = mono16_mapping(img16)
        return self.mono16_map.apply(img16)


def shrunk_size(w: int, h: int, factor: int) -> tuple[int, int]:
    """The size of a w x h picture shrunk by ``factor`` (:func:`shrink`)."""
    return max(w // factor, 1), max(h // factor, 1)


def shrink(gray: np.ndarray, factor: int) -> np.ndarray:
    """A picture shrunk by an integer factor, each pixel the mean of the factor x factor block
    it covers (``cv2.INTER_AREA``), as a frontend that runs on a reduced image sees it."""
    h, w = gray.shape[:2]
    size = shrunk_size(w, h, factor)
    return np.ascontiguousarray(cv2.resize(gray, size, interpolation=cv2.INTER_AREA))


PEDESTAL_RATIO = 2.0
"""A 16-bit picture whose darkest pixels (1st percentile) sit more than this many times the
scene's own spread (1st to 99th percentile) above zero is on a pedestal: a thermal camera's
radiometric counts (a 14-bit Boson or Tau scene spans a few hundred counts around 7000-8000).
Shifted to 8 bits, such a scene keeps 10-30 grey levels, under FAST's contrast threshold of 20
on most of the image, and reads as a detection failure that the camera's own frontend, which
rescales, never has. A picture from zero up (a visible camera's 10-16 bits) has no pedestal."""
PEDESTAL_MARGIN = 0.5
"""Headroom of the fixed window on each side of the first frame's spread, as a share of it:
the scene may warm or cool, or a hot object enter, by half its initial spread before
saturating. The first frame's 1st-99th percentiles map to 64-192 of 0-255."""


class Mono16Mapping(NamedTuple):
    """How 16-bit pictures are mapped to 8 bits for a whole run (:func:`mono16_mapping`)."""

    shift: int
    """Right shift that brings the first picture's peak into 8 bits (used without a window)."""
    window: tuple[int, int] | None
    """[lo, hi) counts mapped linearly to 0-255, for pictures on a pedestal (None: the shift)."""
    note: str
    """How the pictures were mapped, for the run's notes."""

    def apply(self, img16: np.ndarray) -> np.ndarray:
        """The 8-bit picture."""
        if self.window is None:
            return (img16 >> self.shift).clip(0, 255).astype(np.uint8)
        lo, hi = self.window
        scaled = (img16.astype(np.float32) - np.float32(lo)) * np.float32(256.0 / (hi - lo))
        return np.clip(scaled, 0, 255).astype(np.uint8)

    def as_dict(self) -> dict[str, Any]:
        """For the manifest (``from_dict`` reads it back)."""
        return {"shift": self.shift, "window": None if self.window is None else list(self.window),
                "note": self.note}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Mono16Mapping:
        window = d.get("window")
        return cls(int(d["shift"]), None if not window else (int(window[0]), int(window[1])),
                   str(d.get("note") or ""))


def mono16_mapping(img16: np.ndarray) -> Mono16Mapping:
    """The 8-bit mapping of 16-bit pictures, from the first one: (shift, window, note).

    Without a pedestal (:data:`PEDESTAL_RATIO`), the shift that brings the first frame's peak
    into 8 bits: a pure scale, so that a gain or exposure change keeps its ratio. On a
    pedestal, the window [lo, hi) of counts mapped linearly to 0-255: the first frame's 1st-99th
    percentiles widened by :data:`PEDESTAL_MARGIN` of their spread each side, and at least 256
    counts wide (never more than one grey level per count). Either is fixed for the run.
    """
    peak = int(img16.max()) if img16.size else 0
    shift = max(peak.bit_length(), 8) - 8
    if img16.size:
        p1, p99 = (int(v) for v in np.percentile(img16, [1, 99]))
    else:
        p1 = p99 = 0
    spread = p99 - p1
    if spread <= 0 or p1 <= PEDESTAL_RATIO * spread:
        return Mono16Mapping(shift, None, f"16-bit pictures shifted right by {shift} bits "
                             f"(fixed from the first frame, peak {peak})")
    margin = max(round(PEDESTAL_MARGIN * spread), (256 - spread + 1) // 2)
    lo, hi = max(p1 - margin, 0), min(p99 + margin, 65536)
    return Mono16Mapping(shift, (lo, hi), (
        f"16-bit pictures on a pedestal (first frame: 1st-99th percentile {p1}-{p99} counts, "
        f"as a thermal camera's): counts {lo}-{hi} mapped linearly to 0-255, fixed from the "
        f"first frame (a shift by {shift} bits would leave {spread >> shift} grey levels)"))


NO_KEYFRAME = "no keyframe yet: a video's pictures are decoded from its first keyframe on"
REORDERED = ("the video has B-frames (pictures come out after later messages), so a message's "
             "stamp is not its picture's; frontdiag reads video encoded without B-frames, as "
             "Foxglove's CompressedVideo requires (x264: bframes=0)")

# Foxglove CompressedVideo formats -> FFmpeg decoder names
VIDEO_CODECS = {"h264": "h264", "h265": "hevc", "hevc": "hevc", "vp9": "vp9", "av1": "av1"}


class VideoDecoder:
    """One video topic's decoder (FFmpeg through PyAV): one message, one picture.

    Foxglove's ``CompressedVideo`` carries exactly one picture per message, with no B-frames
    (no picture waits for a later one), so each message gives its own picture at once; the
    decoder runs on one thread, since frame threading would hold pictures back. Messages before
    the first keyframe, or whose keyframe was lost, give no picture and are skipped with that
    reason, as undecodable messages are. Each packet carries its message's number as its pts,
    so a stream that reorders pictures (B-frames) is seen, not misread: its messages are
    skipped with that reason.
    """

    def __init__(self, topic: str, fmt: str) -> None:
        codec = VIDEO_CODECS.get(fmt)
        if codec is None:
            raise DecodeError(topic, "format", f"unsupported video codec {fmt!r} (supported: "
                                               f"{', '.join(VIDEO_CODECS)})")
        import av

        self.topic = topic
        self.fmt = fmt
        self._av = av
        self._ctx: Any = av.CodecContext.create(codec, "r")  # a VideoCodecContext
        self._ctx.thread_type = "NONE"
        self.pictures = 0
        self.sent = 0

    def __call__(self, data: Any, fmt: str) -> np.ndarray:
        if fmt != self.fmt:
            raise DecodeError(self.topic, "format",
                              f"changes from {self.fmt!r} to {fmt!r} within the topic; "
                              f"decoding starts again at the first {fmt} keyframe")
        buf = bytes(data)
        if not buf:
            raise DecodeError(self.topic, "data", "empty video message")
        packet = self._av.Packet(buf)
        packet.pts = self.sent  # each picture comes out with the number of its message
        self.sent += 1
        try:
            frames = self._ctx.decode(packet)
        except self._av.error.FFmpegError as exc:
            if self.pictures == 0:
                raise DecodeError(self.topic, "data", NO_KEYFRAME) from None
            raise DecodeError(self.topic, "data",
                              f"undecodable {self.fmt} picture ({exc.strerror or exc})") from None
        mine = [f for f in frames if f.pts == packet.pts]
        if frames and not mine:
            # a picture of an earlier message: the stream reorders (B-frames), so a message's
            # stamp is not its picture's
            raise DecodeError(self.topic, "data", REORDERED)
        if not mine:
            raise DecodeError(self.topic, "data", NO_KEYFRAME if self.pictures == 0
                              else f"no {self.fmt} picture in the message")
        self.pictures += 1
        return luma(mine[-1])


def is_keyframe(data: Any, fmt: str) -> bool | None:
    """Whether a video message starts a picture that needs no earlier one: an H.264 IDR
    (NAL type 5) or an H.265 IRAP picture (NAL types 16-21), found by the Annex B start codes
    (00 00 01) Foxglove's CompressedVideo and ffmpeg_image_transport use. None for other
    codecs, which are then decoded from their first message."""
    if fmt not in ("h264", "h265", "hevc"):
        return None
    buf = bytes(data)
    at = buf.find(b"\x00\x00\x01")
    while 0 <= at < len(buf) - 3:
        head = buf[at + 3]
        if fmt == "h264":
            if head & 0x1F == 5:
                return True
        elif 16 <= (head >> 1) & 0x3F <= 21:
            return True
        at = buf.find(b"\x00\x00\x01", at + 3)
    return False


# 8-bit pixel formats whose first plane is the luma Y, in limited (video) range unless the
# frame says full; the "j" formats are full range (JPEG's)
_Y_FIRST = frozenset({"yuv420p", "yuv422p", "yuv444p", "yuv440p", "yuv411p", "yuv410p", "nv12",
                      "nv21", "nv16", "nv24"})
_Y_FIRST_FULL = frozenset({"yuvj420p", "yuvj422p", "yuvj444p", "yuvj440p", "gray"})
# limited range Y (16-235) to full range grey (0-255), as FFmpeg's swscale converts it
_LIMITED_TO_FULL = np.clip(np.round((np.arange(256) - 16) * 255 / 219), 0, 255).astype(np.uint8)
_AVCOL_RANGE_JPEG = 2


def luma(frame: Any) -> np.ndarray:
    """8-bit grey of a decoded video frame: its Y plane, stretched from video range to full
    range where it is in video range (a LUT: 0.3 ms at 1241x376 against 1.8 ms for swscale's
    conversion, with the same values); other pixel formats through swscale."""
    name = frame.format.name
    if name in _Y_FIRST or name in _Y_FIRST_FULL:
        plane = frame.planes[0]
        y = np.frombuffer(plane, np.uint8).reshape(frame.height, plane.line_size)[:, :frame.width]
        if name in _Y_FIRST_FULL or getattr(frame, "color_range", 0) == _AVCOL_RANGE_JPEG:
            return np.array(y)  # a copy: the decoder reuses the frame's memory
        return cv2.LUT(y, _LIMITED_TO_FULL)
    return np.ascontiguousarray(frame.to_ndarray(format="gray"))

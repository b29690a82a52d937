"""The scenario catalogue: which world, which motion, which labels.

A scenario is a list of :class:`Part` s (one world each) driven through a list of
:class:`Segment` s (a motion and the label each sensor gets by construction). Labels never come
from metrics: a segment says "the camera sees only the label bank" or "the robot is parked and
the head pans", and the label follows. Frames within ``MARGIN_S`` of a change of label (or of a
cut between parts) are left unlabelled, because which side of the change they belong to is a
matter of taste. The auto-exposure controller adds ``exposure_step`` on the frame where its
gain steps (see :mod:`frontdiag.sim.run`).

Motion functions map segment-local time (s) to ``(x, y, yaw, pan)`` in the part's world.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from frontdiag.sim import textures as T
from frontdiag.sim.scenes import Builder

Pose = tuple[float, float, float, float]
MotionFn = Callable[[float], Pose]
MARGIN_S = 0.15


@dataclass
class Segment:
    """A stretch of motion with its labels; ``None`` leaves that sensor unlabelled."""

    duration: float
    motion: MotionFn
    camera: str | None = "healthy"
    lidar: str | None = "healthy"
    lights: tuple[float, float] = (1.0, 1.0)  # light level at start and end (linear fade)


@dataclass
class Part:
    """One world and the segments driven in it."""

    build: Callable[[Builder], None]
    segments: list[Segment]
    auto_exposure: bool = True
    name: str = ""

    @property
    def duration(self) -> float:
        return sum(s.duration for s in self.segments)


@dataclass
class Scenario:
    name: str
    summary: str
    shows: str
    default_seconds: float
    make: Callable[[float], list[Part]] = field(repr=False)


# -- motion primitives -------------------------------------------------------------------

def line(x0: float, y0: float, yaw: float, v: float) -> MotionFn:
    c, s = np.cos(yaw), np.sin(yaw)
    return lambda t: (x0 + v * t * c, y0 + v * t * s, yaw, 0.0)


def stop(x0: float, y0: float, yaw: float, v0: float, duration: float) -> MotionFn:
    """Constant deceleration from ``v0`` to rest over ``duration``."""
    c, s = np.cos(yaw), np.sin(yaw)

    def f(t: float) -> Pose:
        t = min(max(t, 0.0), duration)
        d = v0 * (t - t * t / (2 * duration))
        return (x0 + d * c, y0 + d * s, yaw, 0.0)

    return f


def pan(x: float, y: float, yaw: float, amp_deg: float, period: float) -> MotionFn:
    """Parked; the camera head pans sinusoidally about its own optical centre."""
    a = np.radians(amp_deg)
    return lambda t: (x, y, yaw, float(a * np.sin(2 * np.pi * t / period)))


class LoopPath:
    """A rounded rectangle driven counter-clockwise, parametrised by arc length."""

    def __init__(self, x0: float, x1: float, y0: float, y1: float, r: float) -> None:
        pts: list[tuple[float, float]] = []
        # the long sides (along x), as arc-length intervals from the start
        long_side, short_side, turn = x1 - x0 - 2 * r, y1 - y0 - 2 * r, 0.5 * np.pi * r
        second = long_side + 2 * turn + short_side
        self.long_sides = [(0.0, long_side), (second, second + long_side)]
        step = 0.01
        corners = [((x1 - r, y0 + r), -np.pi / 2), ((x1 - r, y1 - r), 0.0),
                   ((x0 + r, y1 - r), np.pi / 2), ((x0 + r, y0 + r), np.pi)]
        starts = [(x0 + r, y0), (x1, y0 + r), (x1 - r, y1), (x0, y1 - r)]
        ends = [(x1 - r, y0), (x1, y1 - r), (x0 + r, y1), (x0, y0 + r)]
        for (sx, sy), (ex, ey), ((cx, cy), a0) in zip(starts, ends, corners, strict=True):
            n = max(2, int(np.hypot(ex - sx, ey - sy) / step))
            pts += list(zip(np.linspace(sx, ex, n, endpoint=False),
                            np.linspace(sy, ey, n, endpoint=False), strict=True))
            m = max(2, int(0.5 * np.pi * r / step))
            for a in np.linspace(a0, a0 + np.pi / 2, m, endpoint=False):
                pts.append((cx + r * np.cos(a), cy + r * np.sin(a)))
        p = np.array(pts)
        d = np.diff(np.vstack([p, p[:1]]), axis=0)
        self.s = np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])
        self.p = np.vstack([p, p[:1]])
        self.yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        self.yaw = np.append(self.yaw, self.yaw[-1])
        self.length = float(self.s[-1])

    def motion(self, s0: float, v: float) -> MotionFn:
        def f(t: float) -> Pose:
            s = (s0 + v * t) % self.length
            yaw = float(np.interp(s, self.s, self.yaw))
            return (float(np.interp(s, self.s, self.p[:, 0])),
                    float(np.interp(s, self.s, self.p[:, 1])), yaw, 0.0)
        return f


# -- worlds ---------------------------------------------------------------------------------

def hall(b: Builder) -> None:
    """The stocked hall: an island of racking inside a ring aisle, racks along the walls, and
    beyond each end of the ring the island's row running on towards the end walls, so a robot
    driving a long side looks down aisles receding in depth, not at a flat end wall."""
    b.floor(-12, 32, -7, 7)
    b.ceiling(-12, 32, -7, 7)
    b.wall_x(-12, 32, 7.0, facing=-1, style="concrete")
    b.wall_x(-12, 32, -7.0, facing=1, style="concrete")
    b.wall_y(-7, 7, -12.0, facing=1, style="concrete")
    b.wall_y(-7, 7, 32.0, facing=-1, style="concrete")
    b.shelving(4.0, 16.0, 0.95, -1, "unique")
    b.shelving(4.0, 16.0, -0.95, 1, "unique")
    b.shelving(-9.2, 29.2, 5.0, 1, "unique")
    b.shelving(-9.2, 29.2, -5.0, -1, "unique")
    # the island's line continues 2 m past the loop's turns (x 1.5-18.5): each long side of
    # the loop looks on down an aisle between it and a wall rack
    for x0, x1 in ((20.6, 29.0), (-9.0, -0.6)):
        b.shelving(x0, x1, 0.95, -1, "unique")
        b.shelving(x0, x1, -0.95, 1, "unique")


def plain_aisle(left: str, right: str, length: float = 60.0,
                bank: list[tuple[float, float]] | None = None) -> Callable[[Builder], None]:
    """A long aisle between two racks, blank floor and ceiling, blank end walls."""
    def build(b: Builder) -> None:
        b.floor(-3, length + 3, -4, 4, textured=False)
        b.ceiling(-3, length + 3, -4, 4)
        b.shelving(0.0, length, 1.6, 1, left, bank=bank)
        b.shelving(0.0, length, -1.6, -1, right, bank=bank)
        b.wall_y(-4, 4, length + 3, style="blank", facing=-1)
        b.wall_y(-4, 4, -3, style="blank", facing=1)
        b.wall_x(-3, length + 3, 4.0, style="blank", facing=-1)
        b.wall_x(-3, length + 3, -4.0, style="blank", facing=1)
    return build


def dock_door(b: Builder) -> None:
    """A wide stocked aisle (6 m) running towards an open dock door; a bright yard beyond.

    Wide, so the LiDAR sees the hall walls at several heights: a narrow rack aisle leaves a
    16-beam LiDAR weak in roll, which is not the condition this scene is about.
    """
    b.floor(-3, 24, -7, 7)
    b.ceiling(-3, 24, -7, 7)
    b.shelving(-2.4, 19.2, 3.0, 1, "unique")
    b.shelving(-2.4, 19.2, -3.0, -1, "unique")
    b.pallets(18.0, 5.0, 3)
    b.pallets(18.0, -5.0, 3)
    b.wall_x(-3, 24, 7.0, facing=-1, style="concrete")
    b.wall_x(-3, 24, -7.0, facing=1, style="concrete")
    b.wall_y(-7, 7, -3.0, facing=1, style="concrete")
    # end wall at x=24 with a 5 m x 4.5 m roller-door opening
    b.wall_y(2.5, 7.0, 24.0, facing=-1, style="concrete")
    b.wall_y(-7.0, -2.5, 24.0, facing=-1, style="concrete")
    h, w = b._size(5.0, 0.5, 80)
    b.w.quad([24.0, 2.5, 5.0], [0, -1, 0], [0, 0, -1], 5.0, 0.5, T.concrete(h, w, b.rng))
    # outside: bright yard and a trailer wall, lit by daylight (emissive: ignores the lights)
    h, w = b._size(36, 20, 20)
    b.w.quad([24.0, -10, 0.0], [1, 0, 0], [0, 1, 0], 36, 20,
             T.concrete(h, w, b.rng, level=130, contrast=18), radiance=3.0, emissive=True,
             kind="daylight")
    h, w = b._size(20, 8, 20)
    b.w.quad([40.0, 10, 8.0], [0, -1, 0], [0, 0, -1], 20, 8, T.poster(h, w, b.rng),
             radiance=3.0, emissive=True, kind="daylight")
    h, w = b._size(120, 40, 2)
    b.w.quad([80.0, 60, 40.0], [0, -1, 0], [0, 0, -1], 120, 40,
             T.blank(h, w, b.rng, level=220, contrast=1.0), radiance=3.0, emissive=True,
             kind="daylight")


def dock_corridor(half: float) -> Callable[[Builder], None]:
    """The loading-dock corridor: long parallel walls (visually textured), no end in range.

    ``half`` is half its length: the run stays more than the LiDAR's range from both ends.
    """
    def build(b: Builder) -> None:
        b.floor(-half, half, -2.5, 2.5)
        h, w = b._size(2 * half, 5, 3)
        b.w.quad([-half, -2.5, 4.5], [1, 0, 0], [0, 1, 0], 2 * half, 5,
                 T.blank(h, w, b.rng, level=110, contrast=1.0), kind="blank")
        b.wall_x(-half, half, 2.5, height=4.5, facing=-1)
        b.wall_x(-half, half, -2.5, height=4.5, facing=1)
    return build


def face_room(face: str) -> Callable[[Builder], None]:
    """A closed room whose far wall at x=16 is a flat shelf face (or a blank wall)."""
    def build(b: Builder) -> None:
        b.plain = 125.0  # blank parts about as bright as the carton face
        b.floor(-6, 16, -10, 10, textured=False)
        b.ceiling(-6, 16, -10, 10)
        b.wall_x(-6, 16, 10.0, style="blank", facing=-1)
        b.wall_x(-6, 16, -10.0, style="blank", facing=1)
        b.wall_y(-10, 10, -6.0, style="blank", facing=1)
        if face == "blank":
            b.wall_y(-10, 10, 16.0, style="blank", facing=-1, height=6.0)
            return
        # a flush wall of cartons: every carton different, all in one plane
        ppm = b.ppm(120)
        hh, ww = int(5.0 * ppm), int(20.0 * ppm)
        tex = np.full((hh, ww), 60, np.uint8)
        y = 0
        while y < hh:
            ch = int(b.rng.uniform(0.35, 0.7) * ppm)
            x = 0
            while x < ww:
                cw = int(b.rng.uniform(0.3, 0.7) * ppm)
                blk = T.cardboard(min(ch, hh - y), min(cw, ww - x), b.rng)
                tex[y:y + blk.shape[0], x:x + blk.shape[1]] = blk
                x += cw + max(1, int(0.01 * ppm))
            y += ch + max(1, int(0.01 * ppm))
        b.w.quad([16.0, 10.0, 5.0], [0, -1, 0], [0, 0, -1], 20.0, 5.0, tex, kind="carton")
        b.wall_y(-10, 10, 16.3, style="blank", facing=-1, height=6.0)
    return build


# -- scenarios ------------------------------------------------------------------------------

_LOOP = LoopPath(1.5, 18.5, -3.0, 3.0, 2.0)


def _healthy_loop(seconds: float) -> list[Part]:
    """Laps of the hall. The camera is labelled healthy along the long sides only: through the
    turns and the short sides between them it sweeps across an end wall and faces a rack front
    ~2 m away, a shelf face filling the view that H explains nearly as well as E,
    so which label applies is a matter of taste and those frames are left unlabelled. The
    LiDAR sees the whole hall and stays healthy throughout."""
    v = 1.2
    # pieces of one lap by distance: the long sides and the turns between them. Boundaries are
    # computed per lap from the lap's start (not accumulated), so float rounding at a lap's end
    # can never leave a zero-length piece to repeat forever.
    cuts = sorted({0.0, _LOOP.length, *(x for side in _LOOP.long_sides for x in side)})
    pieces = [(a, b, "healthy" if any(la <= a and b <= lb for la, lb in _LOOP.long_sides)
               else None) for a, b in itertools.pairwise(cuts) if b - a > 1e-9]
    segs: list[Segment] = []
    for lap in range(int(np.ceil(v * seconds / _LOOP.length)) + 1):
        for a, b, cam in pieces:
            t0 = (lap * _LOOP.length + a) / v
            if t0 >= seconds - 1e-9:
                return [Part(hall, segs, name="hall")]
            t1 = min((lap * _LOOP.length + b) / v, seconds)
            segs.append(Segment(t1 - t0, _LOOP.motion(v * t0, v), camera=cam))
    return [Part(hall, segs, name="hall")]


BANK_LEN = 3.6  # three bays of labelled bins
BANK_PITCH = 14.4  # one bank every twelve bays, so only one is in view
BANK_NEAR, BANK_FAR = 3.0, 8.0  # camera-to-bank distances labelled as clustered


def _label_bank(seconds: float) -> list[Part]:
    """Drive a blank aisle past banks of labels on the left.

    While the nearest bank is 3-8 m ahead it is the only texture in view, and it sits in a box
    of the left third of the image; outside that range the bank is either leaving the image or
    too small to tell clustering from too few features, so those frames are unlabelled.
    """
    v = 1.0 if seconds >= 5.0 else BANK_FAR - BANK_NEAR / max(seconds, 1e-3)
    v = float(np.clip(v, 0.5, 1.2))
    length = v * seconds + BANK_FAR + 2 * BANK_PITCH
    first = 1.2 * np.ceil((BANK_FAR + 0.25) / 1.2)  # banks start on an upright
    banks = [(float(b), float(b) + BANK_LEN) for b in np.arange(first, length, BANK_PITCH)]
    # the camera (0.25 m ahead of the base) starts BANK_FAR before the first bank
    x0 = 0.0
    segs: list[Segment] = []
    t = 0.0
    edges: list[tuple[float, str | None]] = []
    for b0, _ in banks:
        t_in = (b0 - 0.25 - BANK_FAR - x0) / v
        t_out = (b0 - 0.25 - BANK_NEAR - x0) / v
        edges += [(t_in, "feature_clustering"), (t_out, None)]
    cur: str | None = None
    for te, lab in edges:
        te = min(te, seconds)
        if te > t:
            segs.append(Segment(te - t, line(x0 + v * t, -0.4, 0.0, v), camera=cur))
            t = te
        cur = lab
        if t >= seconds:
            break
    if t < seconds:
        segs.append(Segment(seconds - t, line(x0 + v * t, -0.4, 0.0, v), camera=cur))
    ends = length + BANK_FAR
    return [Part(plain_aisle("labels", "blank", length=max(60.0, ends), bank=banks),
                 segs, name="label-bank aisle")]


def _repetitive(seconds: float) -> list[Part]:
    v = min(1.0, 40.0 / max(seconds, 1e-3))
    # long enough that the far end stays ~25 m ahead; no longer, every bay costs render time
    length = 1.2 * np.ceil((2.0 + v * seconds + 25.0) / 1.2)
    return [Part(plain_aisle("repetitive", "repetitive", length=float(length)),
                 [Segment(seconds, line(2.0, 0.0, 0.0, v), camera="repetitive_structure")],
                 name="repetitive aisle")]


def _planar(seconds: float) -> list[Part]:
    d_end = 1.8
    d0 = min(8.0, d_end + 0.8 * seconds)
    v = (d0 - d_end) / max(seconds, 1e-3)
    # the gain is held: as the face fills the view the frame mean drifts, and a gain step
    # here would put a second condition into this scene
    return [Part(face_room("cartons"),
                 [Segment(seconds, line(16.0 - d0, 0.0, 0.0, v), camera="planar_degeneracy")],
                 auto_exposure=False, name="flat shelf face")]


def _side_wall(seconds: float) -> list[Part]:
    """A side-looking camera passing the flat wall of cartons at 3 m: a plane under sideways
    translation, whose image motion is nearly a pure shift (what a rotation-only model gives
    at a very long focal), unlike the approach, whose image expands."""
    d = 3.0
    # the wall spans y = -10..10 m and a view 3 m away spans up to +-3 m (90 deg across): a
    # long run slows down so the view never leaves the wall for the blank walls beside it
    v = min(0.8, 14.0 / max(seconds, 1e-3))
    y0 = -v * seconds / 2

    def slide(t: float) -> Pose:  # driving along +y, camera head turned to the wall (+x)
        return (16.0 - d, y0 + v * t, np.pi / 2, -np.pi / 2)

    return [Part(face_room("cartons"), [Segment(seconds, slide, camera="planar_degeneracy")],
                 auto_exposure=False, name="flat wall, side camera")]


def _blank_wall(seconds: float) -> list[Part]:
    v = min(0.4, 2.0 / max(seconds, 1e-3))
    return [Part(face_room("blank"),
                 [Segment(seconds, line(16.0 - 2.4 - v * seconds, 0.0, 0.0, v),
                          camera="detection_failure")], name="blank wall")]


def _dock_door(seconds: float) -> list[Part]:
    """Up to 8 m short of the door: the bright opening grows to a fifth of the view."""
    v = float(np.clip(14.0 / max(seconds, 1e-3), 0.5, 1.5))
    x0 = 15.75 - v * seconds
    return [Part(dock_door, [Segment(seconds, line(x0, 0.0, 0.0, v))], name="dock door")]


def _dock_corridor(seconds: float) -> list[Part]:
    v = 1.5
    half = v * seconds / 2 + 70.0
    return [Part(dock_corridor(half), [Segment(seconds, line(-v * seconds / 2, 0.3, 0.0, v),
                                         lidar="registration_degeneracy")],
                 name="dock corridor")]


def _parked(seconds: float) -> list[Part]:
    drive = min(3.0, 0.3 * seconds)
    brake = 1.0
    park = max(seconds - drive - brake, 0.5)
    v = 1.0
    x0, y0 = 3.0, -3.0
    x1 = x0 + v * drive
    x2 = x1 + v * brake / 2
    return [Part(hall, [
        Segment(drive, line(x0, y0, 0.0, v)),
        Segment(brake, stop(x1, y0, 0.0, v, brake), camera=None, lidar="healthy"),
        Segment(park, pan(x2, y0, 0.0, 35.0, 6.0), camera="pure_rotation"),
    ], name="parked, panning")]


def _lights_out(seconds: float) -> list[Part]:
    v = min(1.0, 15.0 / max(seconds, 1e-3))
    fade = 0.3
    a = 0.3 * seconds
    dark = 0.4 * seconds
    rest = max(seconds - a - dark - 2 * fade, 0.5)
    y0 = -3.0
    x = 2.0
    segs = []
    for dur, cam, lights in ((a, "healthy", (1.0, 1.0)), (fade, None, (1.0, 0.02)),
                             (dark, "detection_failure", (0.02, 0.02)),
                             (fade, None, (0.02, 1.0)), (rest, "healthy", (1.0, 1.0))):
        segs.append(Segment(dur, line(x, y0, 0.0, v), camera=cam, lights=lights))
        x += v * dur
    return [Part(hall, segs, auto_exposure=False, name="lights out")]


_MIX = (("healthy_loop", 0.22), ("label_bank", 0.1), ("dock_door", 0.14), ("repetitive_aisle", 0.1),
        ("dock_corridor", 0.1), ("planar_approach", 0.1), ("parked_panning", 0.12),
        ("lights_out", 0.12))


def _mixed(seconds: float) -> list[Part]:
    parts: list[Part] = []
    for name, share in _MIX:
        parts += SCENARIOS[name].make(share * seconds)
    return parts


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("healthy_loop", "a loop round a stocked hall at 1.2 m/s",
             "healthy: textured, 3D, translating (camera: the long sides; unlabelled in the "
             "turns); LiDAR well constrained", 12.0, _healthy_loop),
    Scenario("label_bank", "blank aisle with one bank of printed labels at eye height (left)",
             "feature_clustering: every feature in one narrow band of the image", 8.0, _label_bank),
    Scenario("repetitive_aisle", "aisle of identical uprights, crates and bin labels",
             "repetitive_structure: normal feature count, ambiguous descriptors", 8.0, _repetitive),
    Scenario("planar_approach", "driving straight at a flat wall of cartons that fills the view",
             "planar_degeneracy: every match on one plane (H explains them as well as E)",
             8.0, _planar),
    Scenario("side_wall", "a side-looking camera passing a flat wall of cartons at 3 m",
             "planar_degeneracy: every match on one plane, the camera sliding sideways past it",
             8.0, _side_wall),
    Scenario("dock_door", "a stocked aisle towards an open dock door with daylight beyond",
             "exposure_step: auto-exposure steps the gain as the door grows; healthy between",
             12.0, _dock_door),
    Scenario("dock_corridor", "the loading-dock corridor: long parallel walls, no end in range",
             "registration_degeneracy on LiDAR rows; the camera sees textured walls (healthy)",
             8.0, _dock_corridor),
    Scenario("parked_panning", "drive, stop, then pan the camera head while parked",
             "pure_rotation while parked (healthy drive before it)", 10.0, _parked),
    Scenario("lights_out", "driving the hall when the lights go out, then come back",
             "detection_failure in the dark (healthy before and after)", 10.0, _lights_out),
    Scenario("blank_wall", "creeping towards a freshly painted blank wall",
             "detection_failure: nothing for a detector to fire on", 5.0, _blank_wall),
    Scenario("mixed", "one run stringing the scenarios together (cuts between areas)",
             "every condition above, in one recording", 60.0, _mixed),
)}

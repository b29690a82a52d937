"""Which topics analyze reads: the only candidate automatically, otherwise the user says."""

from __future__ import annotations

from dataclasses import dataclass, field

from frontdiag.errors import TopicError
from frontdiag.io import foxglove
from frontdiag.io.camera_info import CAMERA_INFO_TYPES, camera_info_topic_for
from frontdiag.io.images import IMAGE_TYPES
from frontdiag.io.readers import TopicInfo
from frontdiag.io.tf import TF_TYPES

LIDAR_TYPES = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan",
               # Livox drivers' own scan message (frontdiag/lidar/livox.py)
               "livox_ros_driver/msg/CustomMsg", "livox_ros_driver2/msg/CustomMsg",
               "livox_interfaces/msg/CustomMsg",
               # the Velodyne driver's raw packets (frontdiag/lidar/velodyne.py)
               "velodyne_msgs/msg/VelodyneScan",
               *foxglove.LIDAR_TYPES)
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")
"""Poses read as the LiDAR's odometry when --odom-topic names them (a pose topic is never picked
on its own: goals, initial poses and map-frame localisers that jump are pose topics too)."""
_NOT_ODOMETRY = ("ground_truth", "groundtruth", "/gt", "truth", "mocap", "vicon")
# image topics that carry range, not intensity (RGB-D and stereo drivers publish them beside the
# camera: /camera/depth/image, /camera/aligned_depth_to_color/image_raw, .../compressedDepth)
_NOT_INTENSITY = ("depth", "disparity")


def is_depth_topic(topic: str) -> bool:
    """Whether an image topic's name says it holds depth or disparity, not intensity."""
    return any(k in seg for seg in topic.lower().split("/") for k in _NOT_INTENSITY)


@dataclass(frozen=True)
class TopicChoice:
    camera: str | None = None
    camera_type: str | None = None
    camera_info: str | None = None
    lidar: str | None = None
    lidar_type: str | None = None
    odometry: str | None = None
    notes: list[str] = field(default_factory=list)
    tf: str | None = None
    """``/tf``, read for the LiDAR's motion prior where no odometry topic is (io/tf.py)."""
    tf_static: str | None = None
    """``/tf_static``, read for where the LiDAR sits in the odometry's frame (io/tf.py)."""

    @property
    def topics(self) -> list[str]:
        return [t for t in (self.camera, self.camera_info, self.lidar, self.odometry, self.tf,
                            self.tf_static) if t]


def _own_motion(cands: list[TopicInfo]) -> list[TopicInfo]:
    """The candidates whose names do not say they are ground truth (``_NOT_ODOMETRY``)."""
    return [t for t in cands if not any(k in t.topic.lower() for k in _NOT_ODOMETRY)]


def candidates(topics: list[TopicInfo], types: tuple[str, ...]) -> list[TopicInfo]:
    return sorted((t for t in topics if t.msgtype in types), key=lambda t: t.topic)


def _pick(kind: str, option: str, requested: str | None, cands: list[TopicInfo],
          all_topics: list[TopicInfo]) -> TopicInfo | None:
    """The topic of this kind: the one ``requested`` names, else the only candidate.

    ``requested`` may list several names separated by commas (ROS names hold no comma): the
    first the recording holds is read, so one fleet command covers recordings that name the
    same camera differently (``/cam0/image_raw,/stereo/left/image_raw``).
    """
    if requested is not None and "," in requested:
        names = [n.strip() for n in requested.split(",") if n.strip()]
        present = {t.topic for t in all_topics}
        first = next((n for n in names if n in present), None)
        if first is None:
            raise TopicError(f"none of the topics {', '.join(names)} is in the recording",
                             candidates=[c.topic for c in cands],
                             hint=_suggest(option, cands))
        requested = first
    if requested is not None:
        for t in all_topics:
            if t.topic == requested:
                if t not in cands:
                    raise TopicError(f"topic {requested} is {t.msgtype}, not a {kind} topic",
                                     candidates=[c.topic for c in cands],
                                     hint=_suggest(option, cands))
                return t
        raise TopicError(f"topic {requested} is not in the recording",
                         candidates=[c.topic for c in cands], hint=_suggest(option, cands))
    if len(cands) == 1:
        return cands[0]
    if len(cands) > 1:
        lines = "\n".join(f"  {option} {c.topic}    ({c.msgtype.split('/')[-1]}, "
                          f"{c.count if c.count is not None else '?'} msgs)" for c in cands)
        raise TopicError(f"{len(cands)} {kind} topics; choose one by passing:\n{lines}",
                         candidates=[c.topic for c in cands])
    return None


def _suggest(option: str, cands: list[TopicInfo]) -> str:
    if not cands:
        return f"the recording has no topic that {option} can take; see `frontdiag info`"
    return "available: " + ", ".join(f"{option} {c.topic}" for c in cands)


def choose_topics(topics: list[TopicInfo], *, camera_topic: str | None = None,
                  lidar_topic: str | None = None, odom_topic: str | None = None,
                  use_camera: bool = True, use_lidar: bool = True) -> TopicChoice:
    """Pick the camera, CameraInfo, LiDAR and odometry topics analyze will read."""
    notes: list[str] = []
    images = candidates(topics, IMAGE_TYPES)
    cam_cands, depth = images, []
    if camera_topic is None and use_camera:
        depth = [t for t in images if is_depth_topic(t.topic)]
        cam_cands = [t for t in images if t not in depth]
        if depth:
            notes.append("not read as a camera (depth images): "
                         + ", ".join(t.topic for t in depth)
                         + "; pass --camera-topic to read one anyway")
    cam = _pick("camera image", "--camera-topic", camera_topic, cam_cands,
                topics) if use_camera else None
    lid = _pick("LiDAR", "--lidar-topic", lidar_topic,
                candidates(topics, LIDAR_TYPES), topics) if use_lidar else None
    info = None
    if cam is not None:
        infos = [t.topic for t in candidates(topics, CAMERA_INFO_TYPES)]
        info = camera_info_topic_for(cam.topic, infos)
        if info is None:
            notes.append(f"no CameraInfo for {cam.topic}")
    odom = None
    if lid is not None:
        odoms = candidates(topics, (ODOMETRY_TYPE,))
        if odom_topic is not None:
            picked = _pick("odometry", "--odom-topic", odom_topic,
                           candidates(topics, (ODOMETRY_TYPE, *POSE_TYPES)), topics)
            odom = picked.topic if picked else None
        else:
            usable = _own_motion(odoms)
            if len(usable) == 1:
                odom = usable[0].topic
            elif len(usable) > 1:
                notes.append("several odometry topics; LiDAR uses a constant-velocity prior "
                             "(pass --odom-topic to use one)")
    tf = tf_static = None
    if lid is not None:
        tfs = candidates(topics, TF_TYPES)
        # where the LiDAR sits on the robot, for either kind of odometry
        tf_static = next((t.topic for t in tfs if t.topic.strip("/") == "tf_static"), None)
        if odom is None and odom_topic is None:
            dyn = [t for t in tfs if not t.topic.rstrip("/").endswith("tf_static")]
            tf = next((t.topic for t in dyn if t.topic.strip("/") == "tf"),
                      dyn[0].topic if len(dyn) == 1 else None)
    if lid is not None and odom is None and tf is None and odom_topic is None:
        poses = [t.topic for t in _own_motion(candidates(topics, POSE_TYPES))]
        if poses:
            notes.append(f"no odometry for the LiDAR's motion prior; {', '.join(poses[:3])} "
                         "(poses) could give it: pass --odom-topic "
                         f"{poses[0]} if it is the robot's own continuous pose")
    if cam is None and lid is None:
        if depth and use_lidar:
            raise TopicError("no usable sensor topics: the only images are depth images ("
                             + ", ".join(t.topic for t in depth) + ")",
                             hint=f"pass --camera-topic {depth[0].topic} to read one as grey "
                                  "frames anyway")
        if use_camera and use_lidar:
            raise TopicError("no usable sensor topics: the recording has no sensor_msgs/Image, "
                             "CompressedImage, PointCloud2, LaserScan, Livox CustomMsg, "
                             "VelodyneScan or Foxglove image, video, point cloud or scan "
                             "messages",
                             hint="run `frontdiag info LOG` to see what it holds")
        raise TopicError("nothing left to analyze with the sensors that were switched off")
    return TopicChoice(camera=cam.topic if cam else None, camera_type=cam.msgtype if cam else None,
                       camera_info=info, lidar=lid.topic if lid else None,
                       lidar_type=lid.msgtype if lid else None, odometry=odom, notes=notes,
                       tf=tf, tf_static=tf_static)

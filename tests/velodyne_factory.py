"""VLP-16 packets of a simulated scene, laid out as the sensor sends them (VLP-16 User Manual,
rev. E, ch. 9): 12 blocks of 0xFFEE, azimuth (0.01 deg) and 2 firing sequences x 16 lasers of
distance (2 mm) and reflectivity; then a 4-byte timestamp (us past the hour), the return mode
(0x37, strongest) and the product ID (0x22, VLP-16)."""

from __future__ import annotations

import struct

import numpy as np

from frontdiag.lidar.synth import cast, hall_scene

VLP16_ELEV_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], float)
FIRING_US = 2.304  # between lasers of a sequence
SEQUENCE_US = 55.296  # between firing sequences
BLOCK_US = 2 * SEQUENCE_US
PACKET_SIZE = 1206


def firing_geometry(n_packets: int, rpm: float = 600.0, az0_deg: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per packet, block, sequence and laser: the time (s after the first firing), the azimuth
    (deg, clockwise from x) and the elevation (deg) of each firing."""
    deg_per_us = rpm * 360.0 / 60.0 * 1e-6
    p = np.arange(n_packets)[:, None, None, None]
    b = np.arange(12)[None, :, None, None]
    s = np.arange(2)[None, None, :, None]
    j = np.arange(16)[None, None, None, :]
    t_us = (p * 12 + b) * BLOCK_US + s * SEQUENCE_US + j * FIRING_US
    az = (az0_deg + t_us * deg_per_us) % 360.0
    elev = np.broadcast_to(VLP16_ELEV_DEG[None, None, None, :], az.shape)
    return t_us * 1e-6, az, elev


def directions(az_deg: np.ndarray, elev_deg: np.ndarray) -> np.ndarray:
    """Unit rays in the ROS driver's frame (x forward, y left, z up; azimuth clockwise)."""
    a, w = np.radians(az_deg), np.radians(elev_deg)
    return np.stack([np.cos(w) * np.cos(a), -np.cos(w) * np.sin(a), np.sin(w)], axis=-1)


def vlp16_scan(pose: np.ndarray, t0_s: float, *, rpm: float = 600.0, noise_m: float = 0.0,
               seed: int = 0) -> tuple[list[tuple[float, bytes]], np.ndarray, np.ndarray]:
    """One revolution of a static VLP-16 at ``pose`` in the hall: the packets (stamp, bytes),
    and the points it measured (in the sensor frame, quantised as sent) with their times."""
    n_packets = int(np.ceil(60.0 / rpm / (12 * BLOCK_US * 1e-6)))
    t, az, elev = firing_geometry(n_packets, rpm)
    d = directions(az, elev).reshape(-1, 3)
    d_w = d @ pose[:3, :3].T
    o_w = np.broadcast_to(pose[:3, 3], d_w.shape)
    r = cast(hall_scene(), o_w, d_w)
    r = r + np.random.default_rng(seed).normal(0, noise_m, r.shape)
    units = np.where(np.isfinite(r) & (r > 0.5) & (r < 100.0), np.round(r / 0.002), 0)
    units = units.astype(np.uint16).reshape(n_packets, 12, 2, 16)
    packets = []
    for p in range(n_packets):
        body = bytearray()
        for blk in range(12):
            body += struct.pack("<HH", 0xEEFF, round(az[p, blk, 0, 0] * 100) % 36000)
            for s in range(2):
                for j in range(16):
                    body += struct.pack("<HB", int(units[p, blk, s, j]), 100)
        # a packet's time is its first firing's (the manual's "time of the first data point")
        t_first_us = int((t0_s + t[p, 0, 0, 0]) * 1e6) % 3_600_000_000
        body += struct.pack("<IBB", t_first_us, 0x37, 0x22)
        assert len(body) == PACKET_SIZE
        packets.append((t0_s + float(t[p, 0, 0, 0]), bytes(body)))
    r_q = units.reshape(-1).astype(np.float64) * 0.002
    ok = r_q > 0
    return packets, d[ok] * r_q[ok, None], t.reshape(-1)[ok]


def scan_msg(packets: list[tuple[float, bytes]], frame_id: str = "velodyne") -> dict:
    """Fields of a velodyne_msgs/VelodyneScan (ROS 2 layout) stamped with its last packet."""
    def stamp(s: float) -> dict:
        ns = round(s * 1e9)
        return {"sec": ns // 10**9, "nanosec": ns % 10**9}

    return {"header": {"stamp": stamp(packets[-1][0]), "frame_id": frame_id},
            "packets": [{"stamp": stamp(s), "data": np.frombuffer(b, np.uint8)}
                        for s, b in packets]}

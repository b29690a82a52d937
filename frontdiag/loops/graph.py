"""Pose graphs in, one typed structure out: g2o (2D and 3D) and TORO (2D) readers, a g2o writer.

Information layouts (the trap the readers exist for):

* g2o stores the upper triangle row by row: ``xx xy xθ yy yθ θθ`` in 2D, 21 values over
  ``(x y z qx qy qz)`` in 3D.
* TORO (``EDGE2``) orders it ``xx xy yy θθ xθ yθ``; read in g2o order, a TORO edge has yy = 0
  on the diagonal and is never positive definite.
* Some published copies store the square root of the information (``sqrt_info=True`` squares it).
* g2o's 3D error uses the quaternion's vector part, which is half the rotation vector for small
  angles, so the rotation block is converted to the rotation-vector tangent (``Ω_φ = JᵀΩJ``,
  ``J = diag(I, I/2)``) used everywhere here.

Every edge is stored pointing forward (``src < dst`` in vertex order): a loop written
later→earlier is inverted and its information carried with the adjoint. Odometry is the first
edge joining vertices adjacent in id order (ids need not be consecutive numbers: keyframes
numbered by their frame, or a graph whose dropped vertices left gaps); every other edge is a
loop candidate.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from frontdiag.errors import RecordingError
from frontdiag.loops import lie

log = logging.getLogger(__name__)

F = NDArray[np.float64]
I64 = NDArray[np.int64]

G2O_2D_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
TORO_2D = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))
_VERTEX = {"VERTEX_SE2": 2, "VERTEX2": 2, "VERTEX_SE3:QUAT": 3}
_EDGE = {"EDGE_SE2": 2, "EDGE2": 2, "EDGE_SE3:QUAT": 3}
_IGNORED = {"FIX", "VERTEX_XY", "EDGE_SE2_XY", "ROBOTLASER1", "PARAMS_SE2OFFSET"}


def looks_like_graph(path: Path) -> bool:
    """Whether the file starts like a pose graph this module reads: a vertex or edge tag
    opening one of its first 20 lines (for the hint of a reader that was given one)."""
    try:
        with Path(path).open("rb") as fh:
            head = fh.read(4096).decode("ascii", "replace")
    except OSError:
        return False
    tags = _VERTEX.keys() | _EDGE.keys()
    return any(line.split(maxsplit=1)[:1] and line.split(maxsplit=1)[0] in tags
               for line in head.splitlines()[:20])


class GraphError(RecordingError):
    """A pose-graph file that cannot be read as asked (exit 2, one line naming the edge)."""


@dataclass
class PoseGraph:
    """A pose graph with every edge oriented forward.

    ``ids`` are the vertex ids in increasing order; edges refer to rows of ``ids``.
    ``Z[e]`` is the pose of ``dst`` in the frame of ``src``; ``info[e]`` its information over
    the right-perturbation tangent at ``dst`` (translation first).
    """

    dim: int
    ids: I64
    src: I64
    dst: I64
    Z: F
    info: F
    line: I64
    flipped: NDArray[np.bool_]
    initial: F | None = None
    """(n, d+1, d+1) vertex estimates from the file, or None when it has none."""
    path: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def n_vertices(self) -> int:
        return int(self.ids.shape[0])

    @property
    def n_edges(self) -> int:
        return int(self.src.shape[0])

    @property
    def k(self) -> int:
        return lie.tangent_dim(self.dim)

    def odometry_mask(self, max_gap: int = 1) -> NDArray[np.bool_]:
        """Edges treated as odometry: the first edge joining vertices adjacent in id order (and,
        with ``max_gap`` > 1, every edge spanning at most that many vertices in id order, which
        is then not audited). Ids 0, 7, 15, ... (keyframes numbered by their frame) chain as
        0, 1, 2, ... do."""
        gap = self.dst - self.src  # positions in the sorted ids
        first = np.zeros(self.n_edges, bool)
        consecutive = np.flatnonzero(gap == 1)
        _, first_idx = np.unique(self.src[consecutive], return_index=True)
        first[consecutive[first_idx]] = True
        if max_gap > 1:
            first |= gap <= max_gap
        return first

    def file_ends(self, e: int) -> tuple[int, int]:
        """Edge ``e``'s vertex ids in the order the file writes them (edges are stored
        forward)."""
        a, b = int(self.ids[self.src[e]]), int(self.ids[self.dst[e]])
        return (b, a) if self.flipped[e] else (a, b)

    def edge_name(self, e: int) -> str:
        a, b = self.file_ends(e)
        return f"{self.path}:{int(self.line[e])}: edge {a}->{b}"


def _sym(vals: F, layout: tuple[tuple[int, int], ...], k: int) -> F:
    out = np.zeros((vals.shape[0], k, k))
    for c, (r, q) in enumerate(layout):
        out[:, r, q] = vals[:, c]
        out[:, q, r] = vals[:, c]
    return out


def _upper_layout(k: int) -> tuple[tuple[int, int], ...]:
    return tuple((r, q) for r in range(k) for q in range(r, k))


def read_graph(path: Path | str, *, sqrt_info: bool = False,
               layout: str = "auto") -> PoseGraph:
    """Read a .g2o or TORO .graph file.

    ``layout``: ``auto`` (g2o order for ``EDGE_SE2``/``EDGE_SE3:QUAT``, TORO order for
    ``EDGE2``), ``g2o`` or ``toro`` to force the 2D information order.
    Raises :class:`GraphError` naming the file and line on anything malformed, and on an
    information matrix that is not positive definite.
    """
    path = Path(path)
    if layout not in ("auto", "g2o", "toro"):
        raise GraphError(path, f"--layout {layout!r}: choose auto, g2o or toro")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise GraphError(path, "no such file") from None
    except IsADirectoryError:
        raise GraphError(path, "a folder; `frontdiag loops` reads one pose-graph file (g2o "
                               "VERTEX_SE2/SE3 and EDGE_SE2/SE3, or TORO VERTEX2/EDGE2)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GraphError(path, f"cannot read ({exc})") from None
    dim = 0
    vid: list[int] = []
    vrows: list[list[float]] = []
    vline: list[int] = []
    e_ij: list[tuple[int, int]] = []
    e_rows: list[list[float]] = []
    e_line: list[int] = []
    e_toro: list[bool] = []
    skipped: dict[str, int] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        tok = raw.split()
        if not tok or tok[0].startswith("#"):
            continue
        tag = tok[0]
        d = _VERTEX.get(tag) or _EDGE.get(tag)
        if d is None:
            skipped[tag] = skipped.get(tag, 0) + 1
            continue
        if dim and d != dim:
            raise GraphError(path, f"line {lineno}: {tag} mixes 2D and 3D elements")
        dim = d
        try:
            if tag in _VERTEX:
                need = 5 if d == 2 else 9
                vid.append(int(tok[1]))
                vline.append(lineno)
                vrows.append([float(x) for x in tok[2:need]])
                if len(vrows[-1]) != need - 2:
                    raise ValueError("too few values")
            else:
                need = 3 + 3 + 6 if d == 2 else 3 + 7 + 21
                if len(tok) < need:
                    raise ValueError(f"{len(tok) - 3} values, expected {need - 3}")
                e_ij.append((int(tok[1]), int(tok[2])))
                e_rows.append([float(x) for x in tok[3:need]])
                e_line.append(lineno)
                e_toro.append(tag == "EDGE2")
        except (ValueError, IndexError) as exc:
            raise GraphError(path, f"line {lineno}: malformed {tag} ({exc})") from None
    if not e_ij:
        raise GraphError(path, "no EDGE_SE2, EDGE2 or EDGE_SE3:QUAT lines: not a pose graph",
                         hint="frontdiag loops reads g2o and TORO pose-graph files")
    notes = [f"skipped {n} {tag} line(s)" for tag, n in sorted(skipped.items())
             if tag not in _IGNORED or n]
    ij = np.asarray(e_ij, dtype=np.int64)
    rows = np.asarray(e_rows, dtype=float)
    lines = np.asarray(e_line, dtype=np.int64)
    k = lie.tangent_dim(dim)
    n_meas = 3 if dim == 2 else 7
    bad_meas = np.flatnonzero(~np.all(np.isfinite(rows[:, :n_meas]), axis=1))
    if bad_meas.size:
        e = bad_meas[0]
        raise GraphError(path, f"line {lines[e]}: edge {ij[e, 0]}->{ij[e, 1]}: measurement "
                               f"{' '.join(f'{v:g}' for v in rows[e, :n_meas])} is not finite "
                               f"({bad_meas.size} such edge(s))",
                         hint="fix or drop the edge; a NaN pose cannot be tested")
    V = np.asarray(vrows, dtype=float) if vrows else np.zeros((0, 3))
    if vrows:
        bad_v = np.flatnonzero(~np.all(np.isfinite(V), axis=1))
        if bad_v.size:
            raise GraphError(path, f"line {vline[bad_v[0]]}: vertex {vid[bad_v[0]]}: estimate is "
                                   f"not finite ({bad_v.size} such vertex line(s))")
        if dim == 3:
            # a vertex estimate is only a starting guess: any finite non-zero quaternion is
            # normalised (scaled first, so that a huge component does not overflow the norm)
            qv = V[:, 3:7]
            big = np.max(np.abs(qv), axis=1)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                qn_v = big * np.linalg.norm(qv / big[:, None], axis=1)
            bad_q = np.flatnonzero(~(np.isfinite(qn_v) & (qn_v > 0)))
            if bad_q.size:
                raise GraphError(path, f"line {vline[bad_q[0]]}: vertex {vid[bad_q[0]]}: "
                                       f"quaternion {' '.join(f'{v:g}' for v in qv[bad_q[0]])} "
                                       "has no direction (zero or overflowing norm)")
            V[:, 3:7] = qv / qn_v[:, None]
    if dim == 2:
        Z = lie.se2(rows[:, 0], rows[:, 1], rows[:, 2])
        toro = np.asarray(e_toro) if layout == "auto" else np.full(len(e_toro), layout == "toro")
        info = np.where(toro[:, None, None], _sym(rows[:, 3:], TORO_2D, 3),
                        _sym(rows[:, 3:], G2O_2D_UPPER, 3))
    else:
        q = rows[:, 3:7]
        qn = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(~(np.abs(qn - 1.0) < 1e-3))
        if bad.size:
            raise GraphError(path, f"line {lines[bad[0]]}: quaternion norm {qn[bad[0]]:.4g}, "
                                   "expected 1")
        Z = lie.se3(rows[:, :3], q / qn[:, None])
        info = _sym(rows[:, 7:], _upper_layout(6), 6)
    if sqrt_info:
        info = info @ info
    if dim == 3:
        J = np.diag([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])
        info = J @ info @ J
    _check_pd(path, info, ij, lines, toro_hint=dim == 2)
    if vid:
        # a file that defines its vertices must define every vertex its edges join (g2o
        # refuses to load it otherwise); a file of edges alone takes its ids from the edges
        known = np.unique(np.asarray(vid, dtype=np.int64))
        undefined = ~np.isin(ij, known)
        if undefined.any():
            e, side = (int(v) for v in np.argwhere(undefined)[0])
            raise GraphError(path, f"line {lines[e]}: edge {ij[e, 0]}->{ij[e, 1]}: vertex "
                                   f"{ij[e, side]} has no VERTEX line "
                                   f"({int(undefined.any(axis=1).sum())} such edge(s))",
                             hint="add the vertex or drop the edge")
        dup = np.flatnonzero(np.bincount(np.searchsorted(known, vid)) > 1)
        if dup.size:
            notes.append(f"{dup.size} vertex id(s) defined more than once (first: "
                         f"{known[dup[0]]}); the last definition is the starting estimate")
    ids = np.unique(np.concatenate([ij.ravel(), np.asarray(vid, dtype=np.int64)]))
    src = np.searchsorted(ids, ij[:, 0])
    dst = np.searchsorted(ids, ij[:, 1])
    self_loop = np.flatnonzero(src == dst)
    if self_loop.size:
        raise GraphError(path, f"line {lines[self_loop[0]]}: edge joins vertex "
                               f"{ij[self_loop[0], 0]} to itself")
    flipped = src > dst
    if flipped.any():
        f = np.flatnonzero(flipped)
        Ad = lie.adjoint(Z[f])
        Adinv = np.linalg.inv(Ad)
        # (Z Exp(ξ))⁻¹ = Z⁻¹ Exp(-Ad(Z) ξ): Ω' = Ad⁻ᵀ Ω Ad⁻¹
        info[f] = np.swapaxes(Adinv, -1, -2) @ info[f] @ Adinv
        Z[f] = lie.inv(Z[f])
        src[f], dst[f] = dst[f], src[f].copy()
    initial = None
    if vid:
        P = lie.se2(V[:, 0], V[:, 1], V[:, 2]) if dim == 2 else lie.se3(V[:, :3], V[:, 3:7])
        initial = np.tile(np.eye(dim + 1), (ids.shape[0], 1, 1))
        initial[np.searchsorted(ids, np.asarray(vid, dtype=np.int64))] = P
    del k
    return PoseGraph(dim=dim, ids=ids, src=src, dst=dst, Z=Z, info=info, line=lines,
                     flipped=flipped, initial=initial, path=str(path), notes=notes)


def _check_pd(path: Path, info: F, ij: I64, lines: I64, toro_hint: bool) -> None:
    sym_ok = np.all(np.isfinite(info), axis=(1, 2))
    if not sym_ok.all():
        e = int(np.flatnonzero(~sym_ok)[0])
        raise GraphError(path, f"line {lines[e]}: edge {ij[e, 0]}->{ij[e, 1]}: information matrix "
                               f"is not finite ({int((~sym_ok).sum())} such edge(s))",
                         hint="fix or drop the edge's information block")
    eig = np.full((info.shape[0], info.shape[1]), -1.0)
    eig[sym_ok] = np.linalg.eigvalsh(info[sym_ok])
    bad = np.flatnonzero(eig[:, 0] <= 0)
    if bad.size == 0:
        return
    e = bad[0]
    hint = ("a TORO file read in g2o order (or the reverse) looks like this: try "
            "--layout toro / --layout g2o" if toro_hint else
            "check the information block of this edge")
    raise GraphError(path, f"line {lines[e]}: edge {ij[e, 0]}->{ij[e, 1]}: information matrix "
                           f"is not positive definite (smallest eigenvalue {eig[e, 0]:.3g}; "
                           f"{bad.size} such edge(s))", hint=hint)


def write_g2o(path: Path | str, graph: PoseGraph, poses: F | None = None) -> Path:
    """Write a graph as g2o (vertices from ``poses`` or ``graph.initial``, edges forward)."""
    path = Path(path)
    P = poses if poses is not None else graph.initial
    out: list[str] = []
    if graph.dim == 2:
        if P is not None:
            th = np.arctan2(P[:, 1, 0], P[:, 0, 0])
            for i, vid in enumerate(graph.ids):
                out.append(f"VERTEX_SE2 {vid} {P[i, 0, 2]:.9g} {P[i, 1, 2]:.9g} {th[i]:.9g}")
        th = np.arctan2(graph.Z[:, 1, 0], graph.Z[:, 0, 0])
        for e in range(graph.n_edges):
            Om = graph.info[e]
            vals = " ".join(f"{Om[r, q]:.9g}" for r, q in G2O_2D_UPPER)
            out.append(f"EDGE_SE2 {graph.ids[graph.src[e]]} {graph.ids[graph.dst[e]]} "
                       f"{graph.Z[e, 0, 2]:.9g} {graph.Z[e, 1, 2]:.9g} {th[e]:.9g} {vals}")
    else:
        from scipy.spatial.transform import Rotation

        if P is not None:
            q = Rotation.from_matrix(P[:, :3, :3]).as_quat()
            for i, vid in enumerate(graph.ids):
                vals = " ".join(f"{v:.9g}" for v in (*P[i, :3, 3], *q[i]))
                out.append(f"VERTEX_SE3:QUAT {vid} {vals}")
        q = Rotation.from_matrix(graph.Z[:, :3, :3]).as_quat()
        Jinv = np.diag([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
        info = Jinv @ graph.info @ Jinv
        for e in range(graph.n_edges):
            vals = " ".join(f"{v:.9g}" for v in (*graph.Z[e, :3, 3], *q[e]))
            ivals = " ".join(f"{info[e, r, c]:.9g}" for r, c in _upper_layout(6))
            out.append(f"EDGE_SE3:QUAT {graph.ids[graph.src[e]]} {graph.ids[graph.dst[e]]} "
                       f"{vals} {ivals}")
    path.write_text("\n".join(out) + "\n")
    return path

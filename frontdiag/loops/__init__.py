"""Loop-closure audit of pose graphs: a sibling of camera/ and lidar/ that reads graphs.

    from frontdiag.loops import read_graph, audit
    result = audit(read_graph("run.g2o"))
    result.table        # one row per loop: residual, χ², fold fraction, group, verdict, reason
"""

from __future__ import annotations

from frontdiag.loops.audit import LoopAudit, audit, summary
from frontdiag.loops.graph import GraphError, PoseGraph, read_graph, write_g2o

__all__ = ["GraphError", "LoopAudit", "PoseGraph", "audit", "read_graph", "summary", "write_g2o"]

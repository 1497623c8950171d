# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Global pose-graph optimisation over the keyframes: the baseline the seed avoids (benchmarks).

Seed 001 exists because re-optimising the whole pose graph after every loop
closure is too slow for a cheap robot. This module is that baseline, so the
benchmark can measure the difference: nodes are the keyframe poses (m, m,
rad), edges the dead-reckoning motion between consecutive keyframes and the
loop closures' registrations; :func:`optimise` solves the nonlinear least
squares problem with ``scipy.optimize.least_squares`` (trust-region
reflective, sparse finite-difference Jacobian), the first node fixed.

:class:`GraphCorrector` is the improved variant
(:class:`~robot_calib.methods.loop_closure_correction.improved.ImprovedLoopClosure`)
that, instead of the seed's direct correction, adds each
accepted closure to the graph, re-optimises all of it, and continues from the
optimised pose of the current frame (the global-optimisation way).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import time
from typing import Optional

import numpy as np
from robot_calib.core.geometry import se2_between, se2_compose, se2_inverse, wrap_angle
from robot_calib.methods.loop_closure_correction.common import Candidate
from robot_calib.methods.loop_closure_correction.improved import ImprovedLoopClosure
from robot_calib.methods.loop_closure_correction.params import LoopClosureParams


@dataclass
class Edge:
    """A relative-pose constraint: node ``j`` seen from node ``i`` (m, m, rad) with sigmas."""

    i: int
    j: int
    z: np.ndarray
    sigma_xy: float
    sigma_yaw: float


def optimise(poses: np.ndarray, edges: list, max_nfev: int = 50) -> tuple[np.ndarray, dict]:
    """
    Optimise node poses (N, 3) under the edges; node 0 stays fixed.

    :param poses: (N, 3) initial poses (m, m, rad).
    :param edges: :class:`Edge` list.
    :param max_nfev: largest number of function evaluations.
    :return: optimised poses (N, 3) and ``{'seconds', 'nfev', 'cost', 'nodes', 'edges'}``.
    """
    start = time.perf_counter()
    poses = np.asarray(poses, dtype=float)
    n = len(poses)
    if n < 2 or not edges:
        return poses.copy(), {'seconds': 0.0, 'nfev': 0, 'cost': 0.0, 'nodes': n,
                              'edges': len(edges)}
    ii = np.array([e.i for e in edges])
    jj = np.array([e.j for e in edges])
    z = np.array([e.z for e in edges])
    w = np.array([[1 / e.sigma_xy, 1 / e.sigma_xy, 1 / e.sigma_yaw] for e in edges])

    def residual(x: np.ndarray) -> np.ndarray:
        p = np.vstack((poses[:1], x.reshape(-1, 3)))
        a, b = p[ii], p[jj]
        c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
        dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        rel = np.column_stack((c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]))
        r = rel - z
        r[:, 2] = np.angle(np.exp(1j * r[:, 2]))
        return (r * w).ravel()

    from scipy.optimize import least_squares  # here: 0.3 s of start-up
    from scipy.sparse import lil_matrix

    sparsity = lil_matrix((3 * len(edges), 3 * (n - 1)), dtype=int)
    for k, (i, j) in enumerate(zip(ii, jj)):
        for node in (i, j):
            if node > 0:
                sparsity[3 * k:3 * k + 3, 3 * (node - 1):3 * node] = 1
    sol = least_squares(residual, poses[1:].ravel(), jac_sparsity=sparsity, method='trf',
                        max_nfev=max_nfev, x_scale='jac')
    out = np.vstack((poses[:1], sol.x.reshape(-1, 3)))
    out[:, 2] = wrap_angle(out[:, 2])
    return out, {'seconds': time.perf_counter() - start, 'nfev': int(sol.nfev),
                 'cost': float(sol.cost), 'nodes': n, 'edges': len(edges)}


class GraphCorrector(ImprovedLoopClosure):
    """
    Loop closures applied by global pose-graph optimisation (the benchmark baseline).

    Same keyframes, detection, registration and refusals as the improved
    corrector; an accepted closure adds a loop edge and the whole graph of
    keyframes (plus the current frame) is re-optimised. ``graph_seconds``
    lists the time of each optimisation (s).

    :param params: corrector parameters.
    :param odom_sigma: (metres per metre, rad per s) growth of the odometry edge sigmas.
    """

    def __init__(self, params: Optional[LoopClosureParams] = None,
                 odom_sigma: tuple = (0.02, 0.002)):
        """Create the corrector and an empty graph."""
        self.odom_sigma = odom_sigma
        super().__init__(params)

    def reset(self) -> None:
        """Forget the state and the graph; keep the parameters and mountings."""
        super().reset()
        # closure nodes: the frames where closures were made (t, raw pose, pose, kf id, z)
        self.closure_nodes: list[dict] = []
        self.graph_seconds: list[float] = []
        self.graph_cpu_seconds: list[float] = []

    def graph_nodes(self) -> int:
        """Return the nodes of the graph: keyframes (the local-check reference included)."""
        return len(self.map.keyframes) + len(self.closure_nodes)

    def _apply(self, t: float, best: Candidate, pose: np.ndarray) -> None:
        keyframes = self.map.keyframes
        kfs = [k for k in keyframes.values() if k.kid >= 0]
        z_new = se2_inverse(best.match.pose)               # current frame seen from the kf
        current = {'t': t, 'raw': self.raw.copy(), 'pose': pose.copy(),
                   'kf': best.keyframe, 'z': z_new}
        self.closure_nodes = [c for c in self.closure_nodes if c['kf'] in keyframes]
        nodes = [('k', k.t, k.raw, k.pose, k) for k in kfs]
        nodes += [('c', c['t'], c['raw'], c['pose'], c) for c in self.closure_nodes + [current]]
        nodes.sort(key=lambda n: n[1])
        index = {id(n[4]): i for i, n in enumerate(nodes)}
        kf_index = {n[4].kid: i for i, n in enumerate(nodes) if n[0] == 'k'}
        edges = []
        for i in range(len(nodes) - 1):
            z = se2_between(nodes[i][2], nodes[i + 1][2])
            d = math.hypot(z[0], z[1])
            dt = max(0.0, nodes[i + 1][1] - nodes[i][1])
            edges.append(Edge(i, i + 1, z, 0.01 + self.odom_sigma[0] * d,
                              0.002 + self.odom_sigma[1] * dt))
        for n in nodes:
            if n[0] == 'c' and n[4]['kf'] in kf_index:
                edges.append(Edge(kf_index[n[4]['kf']], index[id(n[4])], n[4]['z'], 0.02, 0.005))
        cpu0 = time.thread_time()
        optimised, info = optimise(np.array([n[3] for n in nodes]), edges)
        self.graph_cpu_seconds.append(time.thread_time() - cpu0)
        self.graph_seconds.append(info['seconds'])
        for i, n in enumerate(nodes):
            if n[0] == 'k':
                n[4].pose = optimised[i]
            else:
                n[4]['pose'] = optimised[i]
        self.closure_nodes.append(current)
        new = current['pose']
        self.correction = se2_compose(new, se2_inverse(self.raw))
        self.sigma_xy, self.sigma_yaw = 0.02, 0.005
        self._last_fix_kf = self.map.next_id
        self.counts['closures_accepted'] += 1

# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Planar scan registration: kiss-icp coarse alignment, then a 2D point-to-line refinement.

This is the shared 2D registration of robot_calib (loop closure and wheel
calibration use it). The stable entry point is::

    register(source_points, target_points, initial_guess=(0, 0, 0),
             params=ScanMatchParams()) -> MatchResult

Convention: the result ``pose = (x, y, yaw)`` (m, m, rad) maps source points
into the target frame, ``target ~= R(yaw) source + (x, y)``; in other words it
is the pose of the source scan's frame seen from the target scan's frame
(``se2_between(target_pose, source_pose)`` when both poses are known in a
common frame). ``initial_guess`` uses the same convention.

Stages
------
1. **Coarse (kiss-icp, optional)**: the target points become a kiss-icp voxel
   hash map (``kiss_icp.mapping.VoxelHashMap``, points as ``(x, y, 0)``) and the
   source is aligned to it with ``kiss_icp.registration.Registration.
   align_points_to_map`` (point-to-point Gauss-Newton with a Geman-McClure
   kernel, kiss-icp's C++ core). Two passes: a wide correspondence gate for the
   basin, then a narrower one. The 4x4 result is projected onto SE(2) (its z,
   roll and pitch stay zero for planar input). kiss-icp's odometry pipeline
   (``KissICP``, adaptive threshold, motion compensation) is not used: pairwise
   registration only needs the map and the aligner. kiss-icp returns no inlier
   count or information matrix, hence stage 2.
2. **Refinement (ours)**: point-to-line Gauss-Newton (Censi's PL-ICP residual
   without the closed form): each source point is matched to its nearest target
   point, the residual is the distance to the target's local line, whose normal
   comes from a PCA of the target point's ``normal_neighbours`` nearest
   neighbours; correspondences farther than a gate that shrinks from
   ``refine_max_correspondence`` to ``refine_min_correspondence`` are dropped and
   the rest weighted by a Cauchy kernel (scale ``robust_scale``). The nearest
   target points are tracked between iterations (:class:`_Nearest`): a point
   is searched in the KD-tree again only when its move since the last search
   could have changed its nearest point, so the answer is the KD-tree's own
   and the result unchanged (about 13 % of the points searched per iteration
   in the wheel calibration's matches).

Quality: the Gauss-Newton Hessian ``H = sum J^T J`` (J = [n^T, n^T R' p]) of the
final inliers gives the covariance ``sigma^2 H^-1`` and the observability of the
match. ``min_eigenvalue`` is the smallest eigenvalue of ``S H S / n`` with
``S = diag(1, 1, 1 / L)`` (L: RMS range of the source points, m), a
dimensionless number in [0, 1] (0.5 for translation in a square room): near 0 a
direction is unobservable, e.g. the along-corridor translation in a
featureless corridor. ``degenerate`` is set below ``degenerate_eigenvalue``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import importlib.util
import math
from typing import Any, Optional, Sequence, TYPE_CHECKING, Union

import numpy as np
from robot_calib.core.geometry import rot2, wrap_angle
from robot_calib.core.params import param

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# kiss-icp is a named dependency; without it the refinement runs alone. It and scipy.spatial
# are imported where first used: together they cost about 0.5 s of start-up.
HAVE_KISS_ICP = importlib.util.find_spec('kiss_icp') is not None


@dataclass
class ScanMatchParams:
    """Parameters of the 2D scan registration (SI units)."""

    coarse: str = param('kiss_icp', '', 'coarse alignment before the refinement: kiss_icp or '
                        'none', choices=('kiss_icp', 'none'))
    refine: bool = param(True, '', 'run the 2D point-to-line refinement after the coarse stage')
    voxel_size: float = param(0.1, 'm', 'kiss-icp voxel size of the target map',
                              minimum=0.005)
    max_points_per_voxel: int = param(20, '', 'kiss-icp points kept per voxel', minimum=1)
    coarse_max_correspondence: float = param(1.0, 'm', 'kiss-icp correspondence gate of the '
                                             'first (wide) pass', minimum=0.01)
    coarse_kernel: float = param(0.3, 'm', 'kiss-icp Geman-McClure kernel scale of the first '
                                 'pass (the second pass uses a third of both)', minimum=0.001)
    coarse_iterations: int = param(20, '', 'kiss-icp iterations per pass', minimum=1)
    refine_iterations: int = param(20, '', 'point-to-line Gauss-Newton iterations', minimum=2)
    refine_anneal_iterations: int = param(8, '', 'iterations over which the gate shrinks from '
                                          'the wide to the narrow value', minimum=1)
    refine_max_correspondence: float = param(0.8, 'm', 'initial correspondence gate of the '
                                             'refinement', minimum=0.001)
    refine_min_correspondence: float = param(0.1, 'm', 'final correspondence gate of the '
                                             'refinement', minimum=0.001)
    robust_scale: float = param(0.05, 'm', 'Cauchy kernel scale of the point-to-line residuals',
                                minimum=1e-4)
    normal_neighbours: int = param(5, '', 'target neighbours used for each line normal',
                                   minimum=3)
    max_line_spread: float = param(0.3, '', 'largest ratio of the smaller to the larger PCA '
                                   'eigenvalue for a usable line normal', minimum=0.0)
    convergence_translation: float = param(1e-4, 'm', 'translation update that ends the '
                                           'refinement', minimum=0.0)
    convergence_rotation: float = param(1e-5, 'rad', 'rotation update that ends the refinement',
                                        minimum=0.0)
    inlier_distance: float = param(0.1, 'm', 'a source point is an inlier when its nearest '
                                   'target point is closer than this', minimum=0.0)
    min_points: int = param(20, '', 'fewest valid points a scan must have', minimum=3)
    min_inlier_ratio: float = param(0.3, '', 'fewest inliers / source points for ok',
                                    minimum=0.0, maximum=1.0)
    degenerate_eigenvalue: float = param(0.02, '', 'normalised Hessian eigenvalue below which '
                                         'the match is degenerate', minimum=0.0)


@dataclass
class MatchResult:
    """
    Outcome of one registration.

    :ivar pose: (x, y, yaw) (m, m, rad), the source frame seen from the target frame.
    :ivar covariance: 3x3 covariance of ``pose`` (m^2, rad^2), ``sigma^2 H^-1``.
    :ivar hessian: 3x3 Gauss-Newton information ``sum J^T J`` (1, m, m^2 blocks).
    :ivar min_eigenvalue: smallest normalised Hessian eigenvalue (dimensionless, see module).
    :ivar degenerate: a direction of the pose is unobservable (corridor, too few lines).
    :ivar inliers: source points with a target point within ``inlier_distance``.
    :ivar inlier_ratio: ``inliers`` / number of source points.
    :ivar rmse: RMS point-to-line distance of the inliers (m).
    :ivar converged: the refinement (or kiss-icp when alone) converged numerically.
    :ivar iterations: refinement iterations run.
    :ivar coarse_pose: the pose after the coarse stage (m, m, rad).
    :ivar n_source: valid source points; ``n_target``: valid target points.
    :ivar reason: empty when the match ran, else why it could not (e.g. 'few_points').
    """

    pose: np.ndarray
    covariance: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    hessian: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    min_eigenvalue: float = 0.0
    degenerate: bool = True
    inliers: int = 0
    inlier_ratio: float = 0.0
    rmse: float = float('nan')
    converged: bool = False
    iterations: int = 0
    coarse_pose: Optional[np.ndarray] = None
    n_source: int = 0
    n_target: int = 0
    reason: str = ''

    @property
    def ok(self) -> bool:
        """Return True when converged, not degenerate and ``reason`` is empty."""
        return self.converged and not self.degenerate and not self.reason

    def as_dict(self) -> dict:
        """Return a JSON-ready summary (pose in m, m, rad)."""
        return {'x': float(self.pose[0]), 'y': float(self.pose[1]), 'yaw': float(self.pose[2]),
                'min_eigenvalue': float(self.min_eigenvalue), 'degenerate': bool(self.degenerate),
                'inliers': int(self.inliers), 'inlier_ratio': float(self.inlier_ratio),
                'rmse': float(self.rmse), 'converged': bool(self.converged),
                'iterations': int(self.iterations), 'reason': self.reason}


class PreparedScan:
    """
    A target scan made ready for many registrations: KD-tree, line normals, kiss-icp map.

    Prepare the current scan once and register several keyframes against it
    (loop closure does this for its Y candidates).

    :param points: (N, 2) target points (m); non-finite rows are dropped.
    :param params: registration parameters (normals and voxel map use them).
    """

    def __init__(self, points: np.ndarray, params: Optional[ScanMatchParams] = None):
        """Build the KD-tree, the normals and (lazily) the kiss-icp voxel map."""
        self.params = params if params is not None else ScanMatchParams()
        self.points = clean_points(points)
        from scipy.spatial import cKDTree
        self.tree = cKDTree(self.points) if len(self.points) else None
        self.normals, self.normal_ok = _normals(self.points, self.tree,
                                                self.params.normal_neighbours,
                                                self.params.max_line_spread)
        # a missed search returns index len(points): padded rows make it a far, unusable point
        self.padded = np.vstack((self.points, np.full((1, 2), np.inf)))
        self.usable = np.append(self.normal_ok, False)
        self._voxel_map = None

    def __len__(self) -> int:
        """Return the number of valid points."""
        return len(self.points)

    def voxel_map(self):
        """Return the kiss-icp voxel hash map of the points (built on first use)."""
        if self._voxel_map is None:
            kiss = _kiss_binding()
            p = self.params
            max_range = float(np.max(np.linalg.norm(self.points, axis=1))) + 1.0
            vmap = kiss._VoxelHashMap(voxel_size=p.voxel_size, max_distance=max_range,
                                      max_points_per_voxel=p.max_points_per_voxel)
            vmap._add_points(kiss._Vector3dVector(_to3d(self.points)))
            self._voxel_map = vmap
        return self._voxel_map


def _kiss_binding() -> Any:
    """
    Return kiss-icp's compiled module (voxel hash map, registration).

    Its Python wrappers (``kiss_icp.mapping``, ``kiss_icp.registration``) only
    forward to this module but import kiss-icp's configuration layer (pydantic,
    about 0.17 s of a short replay's start-up), so the binding is used directly.
    """
    from kiss_icp.pybind import kiss_icp_pybind
    return kiss_icp_pybind


def clean_points(points: np.ndarray) -> np.ndarray:
    """Return the finite rows of an (N, 2) (or (N, 3)) point array as float64 (N, 2) (m)."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] == 0:
        return np.zeros((0, 2))
    pts = pts[:, :2]
    return np.ascontiguousarray(pts[np.all(np.isfinite(pts), axis=1)])


def _to3d(points: np.ndarray) -> np.ndarray:
    return np.column_stack((points, np.zeros(len(points))))


def _pose_matrix(pose: Sequence[float]) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = rot2(pose[2])
    m[0, 3], m[1, 3] = pose[0], pose[1]
    return m


def _matrix_pose(m: np.ndarray) -> np.ndarray:
    return np.array([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])


def _normals(points: np.ndarray, tree: Optional[cKDTree], k: int,
             max_spread: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return unit line normals (N, 2) from a PCA of each point's k neighbours, and validity.

    The 2x2 covariance of the neighbours has eigenvalues ``m -/+ d`` with ``m``
    half its trace and ``d = hypot((a - c) / 2, b)``; the direction of least
    spread is normal to the major axis at ``0.5 atan2(2 b, a - c)`` (closed
    form, as ``numpy.linalg.eigh`` gives to rounding, up to the sign, which no
    point-to-line term depends on).
    """
    n = len(points)
    if n < 3 or tree is None:
        return np.zeros((n, 2)), np.zeros(n, dtype=bool)
    k = min(k, n)
    _, idx = tree.query(points, k=k)
    x, y = points[:, 0][idx], points[:, 1][idx]        # (N, k) neighbour coordinates (m)
    x -= (x.sum(axis=1) / k)[:, None]
    y -= (y.sum(axis=1) / k)[:, None]
    a = np.einsum('ij,ij->i', x, x) / k                # covariance [[a, b], [b, c]] (m^2)
    b = np.einsum('ij,ij->i', x, y) / k
    c = np.einsum('ij,ij->i', y, y) / k
    half_diff = 0.5 * (a - c)
    mean = 0.5 * (a + c)
    dev = np.hypot(half_diff, b)
    least, most = mean - dev, mean + dev               # eigenvalues, ascending (m^2)
    axis = 0.5 * np.arctan2(b, half_diff)              # major axis direction (rad)
    normals = np.empty((n, 2))
    np.negative(np.sin(axis), out=normals[:, 0])
    np.cos(axis, out=normals[:, 1])
    spread = np.maximum(least, 0.0) / np.maximum(most, 1e-12)
    ok = (spread <= max_spread) & (most > 0)
    return normals, ok


_DAMPING = 1e-9
"""Added to each diagonal entry of the Gauss-Newton Hessian (a regulariser; those entries
are sums of squared normal components, dimensionless, and of squared lever arms, m^2)."""


_ROUNDING = 1e-9
"""Margin (m) for rounding in the distances that decide a nearest point cannot have changed."""


_SEARCH_REACH = 2.0
"""KD-tree searches reach this many gates, so that later queries need fewer."""


class _Nearest:
    """
    Nearest target point of each moved source point, searched again only where it may change.

    A 2-nearest search at position q gives the nearest distance d1 and a lower bound d2 on
    every other target point's distance (the second nearest, or the search gate g0). Moved
    since by delta, the point keeps that nearest target point while ``d2 - d1 > 2 delta``
    (triangle inequality), and a point with no target point within g0 has none within a gate
    g while ``delta < g0 - g``. Only the other points are searched again, so the answer is the
    KD-tree's own: a search bounded by the gate finds a point when its squared distance is
    below the squared gate.
    """

    def __init__(self, target: PreparedScan, n: int):
        """Track ``n`` source points against ``target``; the first query searches them all."""
        self.target = target
        self.at = np.zeros((n, 2))                       # where each was last searched (m)
        self.idx = np.full(n, len(target), dtype=np.intp)
        self.slack = np.full(n, -1.0)                    # (m); negative: search again
        self.miss = np.zeros(n)                          # 1.0: no target within the gate
        self.searched = 0
        """Points searched in the KD-tree so far (the cost the tracking saves)."""

    def query(self, moved: np.ndarray,
              gate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Return each point's nearest target index, squared distance (m^2) and offset (m).

        :param moved: (N, 2) source points in the target frame (m).
        :param gate: search bound (m); the index is ``len(target)`` when none is closer.
        :return: index (N,), squared distance (N,) and ``moved - nearest`` (N, 2), the last
            two also for points beyond the gate (inf where none was ever found).
        """
        again = stale_rows(moved, self.at, self.slack, self.miss, gate)
        if len(again):
            self._search(moved, again, gate)
        offset = moved - self.target.padded[self.idx]
        sq = np.einsum('ij,ij->i', offset, offset)
        return np.where(sq < gate * gate, self.idx, len(self.target)), sq, offset

    def _search(self, moved: np.ndarray, rows: np.ndarray, gate: float) -> None:
        # twice the gate: a point without a target point within it keeps none for a while
        bound = _SEARCH_REACH * gate
        pts = moved[rows]
        dist, idx = self.target.tree.query(pts, k=2, distance_upper_bound=bound)
        self.searched += len(rows)
        found = idx[:, 0] < len(self.target)
        self.at[rows] = pts
        self.idx[rows] = idx[:, 0]
        self.slack[rows] = search_slack(dist, found, bound)
        self.miss[rows] = ~found


def stale_rows(moved: np.ndarray, at: np.ndarray, slack: np.ndarray, miss: np.ndarray,
               gate: float) -> np.ndarray:
    """Return the rows whose nearest target point may have changed (see :class:`_Nearest`)."""
    step = moved - at
    moved_by = np.sqrt(np.einsum('ij,ij->i', step, step))
    return np.flatnonzero(~(moved_by < slack - gate * miss))


def search_slack(dist: np.ndarray, found: np.ndarray, bound: float) -> np.ndarray:
    """Return how far (m) each point may move before it is searched again (:class:`_Nearest`)."""
    gap = 0.5 * (np.minimum(dist[:, 1], bound) - dist[:, 0])   # -inf where none found
    return np.where(found, gap, bound) - _ROUNDING


def _coarse(source: np.ndarray, target: PreparedScan, guess: np.ndarray,
            p: ScanMatchParams) -> tuple[np.ndarray, bool]:
    """Align with kiss-icp in two passes; return the SE(2) pose and whether it ran."""
    kiss = _kiss_binding()
    reg = kiss._Registration(max_num_iterations=p.coarse_iterations,
                             convergence_criterion=1e-4, max_num_threads=1)
    src3 = kiss._Vector3dVector(_to3d(source))
    m = _pose_matrix(guess)
    for gate, kernel in ((p.coarse_max_correspondence, p.coarse_kernel),
                         (p.coarse_max_correspondence / 3.0, p.coarse_kernel / 3.0)):
        m = reg._align_points_to_map(points=src3, voxel_map=target.voxel_map(),
                                     initial_guess=m, max_correspondance_distance=gate,
                                     kernel=kernel)
    pose = _matrix_pose(np.asarray(m))
    if not np.all(np.isfinite(pose)):
        return np.asarray(guess, dtype=float), False
    return pose, True


def _gauss_newton_step(m: np.ndarray) -> Optional[tuple[float, float, float]]:
    """
    Return the step ``-(h + _DAMPING I)^-1 g`` from the 4x4 ``[[h, g], [g^T, .]]`` sums.

    Cofactors of the symmetric 3x3 ``h`` (Cramer's rule: the inverse's adjugate
    over the determinant), in floats; None when the damped ``h`` is singular.
    """
    (a, b, c, x), (_, e, f, y), (_, _, i, z) = m[:3].tolist()
    a += _DAMPING
    e += _DAMPING
    i += _DAMPING
    co_a, co_b, co_c = e * i - f * f, c * f - b * i, b * f - c * e
    det = a * co_a + b * co_b + c * co_c
    if not det:
        return None
    co_e, co_f, co_i = a * i - c * c, b * c - a * f, a * e - b * b
    return (-(co_a * x + co_b * y + co_c * z) / det,
            -(co_b * x + co_e * y + co_f * z) / det,
            -(co_c * x + co_f * y + co_i * z) / det)


def _line_rows(normals: np.ndarray, turned: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """
    Return the point-to-line rows (N, 4) ``[n_x, n_y, n . d(R p)/d yaw, residual]``.

    ``normals`` are the matched target normals, ``turned`` the source points
    rotated (R p, m) and ``offset`` the moved points minus their targets (m); the
    yaw column (m) and the point-line residual (m) follow from them.
    """
    rows = np.empty((len(normals), 4))
    rows[:, :2] = normals
    rows[:, 2] = normals[:, 1] * turned[:, 0] - normals[:, 0] * turned[:, 1]
    rows[:, 3] = np.einsum('ij,ij->i', normals, offset)
    return rows


def _refine(source: np.ndarray, target: PreparedScan, pose: np.ndarray,
            p: ScanMatchParams, nearest: _Nearest) -> tuple[np.ndarray, bool, int]:
    """Point-to-line Gauss-Newton with an annealed gate and a Cauchy kernel."""
    px, py, yaw = (float(v) for v in pose)
    converged = False
    it = 0
    last_step = (math.inf, math.inf)
    n_it = p.refine_iterations
    n_anneal = max(1, min(p.refine_anneal_iterations, n_it - 1))
    ratio = p.refine_min_correspondence / p.refine_max_correspondence
    scale = p.robust_scale
    # a missed query returns index len(points): that row of usable is False
    usable, normals = target.usable, target.normals
    for it in range(1, n_it + 1):
        # The gate shrinks geometrically from the wide to the narrow value, then stays.
        frac = min(1.0, (it - 1) / n_anneal)
        gate = p.refine_max_correspondence * ratio ** frac
        c, s = math.cos(yaw), math.sin(yaw)
        turned = source @ np.array(((c, s), (-s, c)))            # R p (m)
        idx, _, offset = nearest.query(turned + (px, py), gate)
        use = np.flatnonzero(usable[idx])
        if len(use) < 3:
            break
        rows = _line_rows(normals[idx[use]], turned[use], offset[use])
        w = 1.0 / (1.0 + (rows[:, 3] / scale) ** 2)               # Cauchy weights
        step = _gauss_newton_step(rows.T @ (rows * w[:, None]))
        if step is None:
            break
        px, py = px + step[0], py + step[1]
        yaw = wrap_angle(yaw + step[2])
        last_step = (math.hypot(step[0], step[1]), abs(step[2]))
        if (frac >= 1.0 and last_step[0] < p.convergence_translation
                and last_step[1] < p.convergence_rotation):
            converged = True
            break
    if not converged and it == n_it:
        # A slow final creep (sub-mm, sub-mrad steps) still counts as converged.
        converged = last_step[0] < 1e-3 and last_step[1] < 1e-3
    return np.array([px, py, yaw]), converged, it


def _quality(source: np.ndarray, target: PreparedScan, pose: np.ndarray,
             p: ScanMatchParams, result: MatchResult, nearest: _Nearest) -> None:
    """Fill inliers, RMSE, Hessian, covariance and degeneracy of ``result`` at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    turned = source @ np.array(((c, s), (-s, c)))                # R p (m)
    # only inliers are used: the search stops beyond inlier_distance (a miss: index N)
    bound = np.nextafter(p.inlier_distance, np.inf)
    idx, sq, offset = nearest.query(turned + pose[:2], bound)
    inl = np.sqrt(sq) <= p.inlier_distance
    inl &= idx < len(target)
    result.inliers = int(np.count_nonzero(inl))
    result.inlier_ratio = result.inliers / max(1, len(source))
    use = np.flatnonzero(inl & target.usable[idx])
    n = len(use)
    if n < 3:
        result.degenerate = True
        result.min_eigenvalue = 0.0
        return
    rows = _line_rows(target.normals[idx[use]], turned[use], offset[use])
    sums = rows.T @ rows
    h = sums[:3, :3]
    sq_res = float(sums[3, 3])                                    # sum of residuals^2 (m^2)
    result.hessian = h
    result.rmse = math.sqrt(sq_res / n)
    length = max(1e-3, math.sqrt(float(np.einsum('ij,ij->', source, source)) / len(source)))
    scale = np.array((1.0, 1.0, 1.0 / length))
    evals = np.linalg.eigvalsh(h * np.outer(scale, scale) / n)
    result.min_eigenvalue = float(max(0.0, evals[0]))
    result.degenerate = result.min_eigenvalue < p.degenerate_eigenvalue
    sigma2 = max(sq_res / max(1, n - 3), 1e-8)
    result.covariance = sigma2 * _pseudo_inverse(h)


def _pseudo_inverse(h: np.ndarray) -> np.ndarray:
    """
    Return ``numpy.linalg.pinv`` of a symmetric matrix from its eigen-decomposition.

    For a symmetric matrix the singular values are the eigenvalues' magnitudes,
    so pinv's rule (drop those at or below 1e-15 of the largest) reads the same on
    the eigenvalues; one ``eigh`` costs a quarter of pinv's SVD on a 3x3.
    """
    lam, vec = np.linalg.eigh(h)
    mag = np.abs(lam)
    keep = mag > 1e-15 * mag.max()
    return (vec * np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)) @ vec.T


def register(source_points: Union[np.ndarray, PreparedScan],
             target_points: Union[np.ndarray, PreparedScan],
             initial_guess: Sequence[float] = (0.0, 0.0, 0.0),
             params: Optional[ScanMatchParams] = None) -> MatchResult:
    """
    Register a source scan to a target scan in 2D.

    Never raises for bad data: too few valid points give ``reason='few_points'``
    (``ok`` False) and the initial guess as pose.

    :param source_points: (N, 2) source points (m) in the source frame, or a PreparedScan.
    :param target_points: (M, 2) target points (m) in the target frame, or a PreparedScan
        (prepare it once to register many sources against it).
    :param initial_guess: (x, y, yaw) (m, m, rad), source frame in the target frame.
    :param params: registration parameters (defaults when None).
    :return: the :class:`MatchResult` (pose: source frame in the target frame).
    """
    p = params if params is not None else ScanMatchParams()
    source = source_points.points if isinstance(source_points, PreparedScan) \
        else clean_points(source_points)
    target = target_points if isinstance(target_points, PreparedScan) \
        else PreparedScan(target_points, p)
    guess = np.array(initial_guess, dtype=float).reshape(3)
    result = MatchResult(pose=guess.copy(), n_source=len(source), n_target=len(target))
    if not np.all(np.isfinite(guess)):
        result.reason = 'bad_initial_guess'
        return result
    if len(source) < p.min_points or len(target) < p.min_points:
        result.reason = 'few_points'
        return result
    pose = guess
    coarse_ok = False
    if p.coarse == 'kiss_icp' and HAVE_KISS_ICP:
        pose, coarse_ok = _coarse(source, target, guess, p)
    result.coarse_pose = pose.copy()
    nearest = _Nearest(target, len(source))
    if p.refine:
        pose, converged, iters = _refine(source, target, pose, p, nearest)
        result.iterations = iters
    else:
        converged = coarse_ok
    result.pose = np.array([pose[0], pose[1], wrap_angle(pose[2])])
    result.converged = bool(converged)
    _quality(source, target, result.pose, p, result, nearest)
    if result.inlier_ratio < p.min_inlier_ratio:
        result.converged = False
    return result

"""The pose graph: Gauss-Newton over all camera poses from the pairwise edges, and the pruning of loop
edges that disagree with the solution. Solved by SuperLU (single-threaded: the same sums on every run)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from spare_twin.capture.icp import Edge
from spare_twin.capture.se3 import invert, rotation_vector, se3_exp, skew

if TYPE_CHECKING:
    from spare_twin.capture.registration import RegistrationConfig


def edge_residual(poses: np.ndarray, e: Edge) -> np.ndarray:
    """(rotation vector, translation) of Z^-1 T_t^-1 T_s: the edge's disagreement, in the source frame."""
    E = invert(e.T_target_source) @ invert(poses[e.target]) @ poses[e.source]
    return np.concatenate([rotation_vector(E[:3, :3]), E[:3, 3]])


def solve_graph(poses: np.ndarray, edges: list[Edge], iterations: int = 20) -> np.ndarray:
    """Gauss-Newton over the poses (node 0 fixed) minimising sum of r_e^T W_e r_e.

    Poses are updated on the left (T_i <- D(xi_i) T_i, world frame); to first order the residual of edge
    s -> t then changes by Ad(T_s^-1) (xi_s - xi_t). W_e is the edge's information per point times its
    fitness. The sparse system is solved by SuperLU (single-threaded: the same sums on every run)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    n = len(poses)
    poses = poses.copy()
    if n < 2 or not edges:
        return poses
    # a node without edges (a reference-pose run whose pair failed) stays where it is
    prior = 1e-8 * float(np.mean([np.trace(e.information) for e in edges]))
    for _ in range(iterations):
        blocks: dict[tuple[int, int], np.ndarray] = {}
        b = np.zeros(6 * n)
        for e in edges:
            Rt, t = poses[e.source][:3, :3].T, poses[e.source][:3, 3]
            A = np.zeros((6, 6))
            A[:3, :3] = Rt
            A[3:, 3:] = Rt
            A[3:, :3] = -Rt @ skew(t)
            AtW = A.T @ (e.information * e.fitness)
            M = AtW @ A
            g = AtW @ edge_residual(poses, e)
            s, q = e.source, e.target
            for key, sign in (((s, s), 1.0), ((q, q), 1.0), ((s, q), -1.0), ((q, s), -1.0)):
                blocks[key] = blocks.get(key, 0.0) + sign * M
            b[6 * s : 6 * s + 6] += g
            b[6 * q : 6 * q + 6] -= g
        rows, cols, vals = [], [], []
        for (i, j), M in sorted(blocks.items()):
            if i == 0 or j == 0:  # node 0 is fixed
                continue
            ii, jj = np.meshgrid(np.arange(6 * i - 6, 6 * i), np.arange(6 * j - 6, 6 * j), indexing="ij")
            rows.append(ii.ravel())
            cols.append(jj.ravel())
            vals.append(np.ravel(M))
        m = 6 * (n - 1)
        rows.append(np.arange(m))
        cols.append(np.arange(m))
        vals.append(np.full(m, prior))
        H = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
        dx = -np.asarray(spsolve(H, b[6:])).reshape(-1, 6)
        for i in range(1, n):
            poses[i] = se3_exp(dx[i - 1]) @ poses[i]
        if np.abs(dx).max() < 1e-9:
            break
    return poses


def optimise(poses: np.ndarray, edges: list[Edge], cfg: RegistrationConfig) -> tuple[np.ndarray, list[Edge], int]:
    """Solve; drop the loop edge that disagrees most with the solution when beyond the limits; repeat."""
    kept = list(edges)
    pruned = 0
    while True:
        sol = solve_graph(poses, kept)
        worst, worst_k = 1.0, -1
        for k, e in enumerate(kept):
            if abs(e.source - e.target) == 1:
                continue
            r = edge_residual(sol, e)
            off = max(
                np.degrees(np.linalg.norm(r[:3])) / cfg.loop_reject_deg, np.linalg.norm(r[3:]) / cfg.loop_reject_m
            )
            if off > worst:
                worst, worst_k = off, k
        if worst_k < 0:
            return sol, kept, pruned
        del kept[worst_k]
        pruned += 1

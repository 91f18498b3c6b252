"""Link clearance geometry and the flip's joint-space path planner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control import joint_path as jp
from inhand_exp.control.clearance import (
    lowest_corner,
    segment_box_distance,
    segment_box_distances,
)
from inhand_exp.control.hand import HandModel
from inhand_exp.control.joint_path import FreeSpace, JointPath, arrival_times, plan_joint_path


@pytest.mark.parametrize(("seg", "expected"), [
    ((-2.0, 0.0, 2.0, 0.0), 0.0),  # straight through the box
    ((-2.0, 3.0, 2.0, 3.0), 2.0),  # parallel above the top face (hz = 1)
    ((3.0, 0.0, 5.0, 0.0), 2.0),  # beside the right face (hx = 1), pointing away
    ((2.0, 3.0, 4.0, 5.0), math.hypot(1.0, 2.0)),  # nearest to the corner (1, 1)
    ((0.0, 3.0, 3.0, 0.0), 1.0 / math.sqrt(2.0)),  # diagonal: the corner (1, 1) to x + z = 3
])
def test_segment_box_distance(seg, expected):
    assert segment_box_distance(*seg, 1.0, 1.0) == pytest.approx(expected)
    ax, az, bx, bz = seg
    assert segment_box_distance(bx, bz, ax, az, 1.0, 1.0) == pytest.approx(expected)


def test_lowest_corner_of_a_tilted_pole():
    assert lowest_corner(np.array([0.0, 0.3, 0.0]), 0.01, 0.25) == pytest.approx(0.05)
    tilted = lowest_corner(np.array([0.0, 0.3, 0.5]), 0.01, 0.25)
    assert tilted == pytest.approx(0.3 - 0.01 * math.sin(0.5) - 0.25 * math.cos(0.5))


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)


def test_joint_path_round_the_lower_end_stays_clear(model):
    """Finger 0 from off the pole's left side to off its right side: the planner finds a way
    under the lower end (changing elbow branch), and every point of it is clear."""
    pose = np.array([0.0, 0.42, 0.0])
    f = model.fingers[0]
    start = f.ik(pose[:2] + np.array([-0.045, -0.19]), -1)  # off the left side, elbow out
    goal = f.ik(pose[:2] + np.array([0.045, -0.19]), 1)  # off the right side, elbow under
    space = FreeSpace(model, 0, pose, margin=0.005)
    assert space.ok(start) and space.ok(goal)
    way = plan_joint_path(space, start, goal)
    assert way is not None and len(way) >= 3
    np.testing.assert_array_equal(way[0], start)
    np.testing.assert_array_equal(way[-1], goal)
    assert np.sign(way[0][1]) != np.sign(way[-1][1])  # through the straight finger
    for a, b in zip(way, way[1:], strict=False):
        for s in np.linspace(0, 1, 40):
            q = a + (b - a) * s
            assert model.finger_gap(0, q, pose) >= 0.005 - 1e-9
    path = JointPath(way, arrival_times(way, 0.0, 1.0))
    q_end, qd_end, _ = path.reference(1.0)
    np.testing.assert_allclose(q_end, goal)
    np.testing.assert_allclose(qd_end, 0.0)


def test_a_chain_that_cuts_a_corner_is_searched_again_on_a_finer_grid(model):
    """Finger 2 round the lower end of a pole held high and tilted (a state of a hard episode):
    the chain of free cells on the coarse grid cuts the pole's corner between two cell centres,
    so its segments fail the dense check; the search on the grid twice as fine finds a way,
    and every point of it is clear."""
    pose = np.array([0.011, 0.428, 0.138])
    start, goal = np.array([2.59, -1.08]), np.array([1.11, 1.25])
    space = FreeSpace(model, 2, pose, margin=0.006)
    assert space.ok(start) and space.ok(goal)
    chain = jp._chain(space, start, goal)
    assert chain is not None  # connected on the coarse grid ...
    coarse = [start, *(space.cell_q(c) for c in jp._corners(chain)), goal]
    assert jp._shorten(space, coarse) is None  # ... but not along straight segments
    way = plan_joint_path(space, start, goal)
    assert way is not None and space.finer.n == 2 * space.n
    np.testing.assert_array_equal(way[0], start)
    np.testing.assert_array_equal(way[-1], goal)
    for a, b in zip(way, way[1:], strict=False):
        for s in np.linspace(0, 1, 60):
            assert space.ok(a + (b - a) * s)


def test_the_free_pieces_say_when_a_chain_of_cells_exists(model):
    """``FreeSpace.component``: two joint vectors carry one label exactly when the search
    finds a chain of free cells between them (random pairs at a low and a high pose)."""
    rng = np.random.default_rng(3)
    verdicts = {True: 0, False: 0}
    for pose in (np.array([0.0, 0.30, 0.0]), np.array([0.02, 0.44, 0.2])):
        for finger in (0, 2):
            space = FreeSpace(model, finger, pose, margin=0.006)
            f = model.fingers[finger]
            lo, hi = np.array(f.q_lower) + 0.05, np.array(f.q_upper) - 0.05
            qs = [q for q in rng.uniform(lo, hi, size=(80, 2)) if space.ok(q)][:16]
            pairs = list(zip(qs[::2], qs[1::2], strict=False))
            for c in (-0.19, -0.12, 0.0, 0.12):  # off the left side and off the right side
                ends = [f.ik(pose[:2] + np.array([side * 0.045, c]), elbow)
                        for side in (-1, 1) for elbow in (1, -1)]
                ends = [q for q in ends if q is not None and space.ok(q)]
                pairs += [(a, b) for a in ends for b in ends if a is not b]
            for a, b in pairs:
                same = space.component(a) == space.component(b) != 0
                assert same == (jp._chain(space, a, b) is not None)
                verdicts[same] += 1
    assert verdicts[True] > 0 and verdicts[False] > 0, verdicts


def test_no_path_when_the_pole_is_too_low(model):
    pose = np.array([0.0, 0.30, 0.0])  # lower end 5 cm above the palm: no finger passes
    f = model.fingers[0]
    start = f.ik(pose[:2] + np.array([-0.045, -0.19]), -1)
    goal = f.ik(pose[:2] + np.array([0.045, -0.12]), 1)
    space = FreeSpace(model, 0, pose, margin=0.005)
    assert space.ok(start) and space.ok(goal)  # both ends are clear on their own
    assert plan_joint_path(space, start, goal) is None


def test_vectorised_clearance_equals_the_scalar_reference(model):
    """The numpy paths (a whole grid or segment at once) give the plain-float answers to 1e-9:
    segment-box distances, link gaps (palm included) and the free-space test."""
    rng = np.random.default_rng(5)
    seg = rng.uniform(-3.0, 3.0, (4000, 4))
    seg[::7, 2] = seg[::7, 0]  # vertical, horizontal and degenerate segments too
    seg[::11, 3] = seg[::11, 1]
    seg[::13, 2:] = seg[::13, :2]
    many = segment_box_distances(*seg.T, 1.0, 0.5)
    one = [segment_box_distance(*s, 1.0, 0.5) for s in seg]
    np.testing.assert_allclose(many, one, rtol=0, atol=1e-9)
    for i, f in enumerate(model.fingers):
        pose = np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.2, 0.5), rng.uniform(-1.5, 1.5)])
        Q = rng.uniform(np.array(f.q_lower) - 0.3, np.array(f.q_upper) + 0.3, (2000, 2))
        gaps = model.finger_gaps(i, Q, pose)
        ref = np.array([model.finger_gap(i, q, pose) for q in Q])
        assert np.array_equal(np.isinf(gaps), np.isinf(ref)) and np.isinf(ref).any()
        np.testing.assert_allclose(gaps[np.isfinite(ref)], ref[np.isfinite(ref)], atol=1e-9)
        space = FreeSpace(model, i, pose, margin=0.005)
        assert space.ok_many(Q).tolist() == [space.ok(q) for q in Q]
        assert space.grid.any() and not space.grid.all()


def test_segment_box_distance_against_dense_sampling():
    """The closed form against the distance of 2,001 points along each segment (their
    spacing bounds the sampling's error): meeting, passing a corner, beside a face."""
    rng = np.random.default_rng(11)
    hx, hz = 0.01, 0.25
    seg = rng.uniform(-0.4, 0.4, (600, 4))
    seg[::5, 0::2] *= 0.1  # many near the thin box, some through it
    s = np.linspace(0.0, 1.0, 2001)[:, None]
    many = segment_box_distances(*seg.T, hx, hz)
    for (ax, az, bx, bz), d in zip(seg, many, strict=True):
        x, z = ax + s * (bx - ax), az + s * (bz - az)
        sampled = float(np.hypot(np.maximum(np.abs(x) - hx, 0), np.maximum(np.abs(z) - hz, 0))
                        .min())
        spacing = math.hypot(bx - ax, bz - az) / 2000
        assert sampled - spacing - 1e-12 <= d <= sampled + 1e-12
        assert segment_box_distance(ax, az, bx, bz, hx, hz) == pytest.approx(d, abs=1e-12)
    assert (many == 0.0).sum() > 20 and (many > 0.0).sum() > 200


def test_free_space_grid_and_batched_segments_are_the_pointwise_answers(model):
    """The grid (each proximal link checked once, broadcast) is ``ok_many`` of its cells, and
    the shortening's batch of moves holds exactly ``segment_points`` of each move."""
    from inhand_exp.control.joint_path import _segments, segment_points

    rng = np.random.default_rng(2)
    for i in range(3):
        pose = np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.3, 0.5), rng.uniform(-1, 1)])
        space = FreeSpace(model, i, pose, margin=0.006)
        ij = np.stack(np.meshgrid(np.arange(space.n), np.arange(space.n), indexing="ij"), -1)
        flat = space.ok_many(space.lo + space.step * ij.reshape(-1, 2))
        assert np.array_equal(space.grid, flat.reshape(space.n, space.n))
        a = rng.uniform(space.lo, space.hi)
        ends = rng.uniform(space.lo, space.hi, (7, 2))
        ends[3] = a + 1e-3  # a move shorter than one step: its two ends
        points, owner = _segments(a, ends)
        for j, b in enumerate(ends):
            assert np.array_equal(points[owner == j], segment_points(a, b))

"""EKF-SLAM with several robots in one state (``--robot all``, issue 31 item 4).

The filter parks the robots that do not move after the landmarks
(:class:`filters.ekf_slam_store.SlotStore`); these tests hold it to a dense
textbook EKF over the whole joint state, written here with the robots first,
and to its refusals.
"""

from __future__ import annotations

import numpy as np
import pytest

from filters.ekf_slam import EkfSlam
from filters.ekf_slam_config import EkfSlamConfig
from slamcore.errors import GraphSlamError, UnsupportedError
from slamcore.planar import geometry as models
from slamcore.planar.records import Observation, Odometry, PoseSighting

#: Agreement with the dense reference (state: m, rad; covariance: m^2, rad^2).
DENSE_TOL = 1e-9

Q = np.diag([0.02, 0.02, 0.005]) ** 2
R = np.diag([0.1, 0.02]) ** 2
PRIOR = np.eye(3) * 1e-4
STRIDE = 1000  # pose id = robot * STRIDE + frame


class DenseJointEkf:
    """The textbook EKF over ``[robot poses..., landmarks...]`` (standard Jacobians)."""

    def __init__(self, pid: int, wTb: np.ndarray, cov: np.ndarray):
        self.x = np.array(wTb, float)
        self.P = np.array(cov, float)
        self.index = {("pose", pid // STRIDE): 0}
        self.live = {pid // STRIDE: pid}
        self.first = (self.x.copy(), self.P.copy())  # the run's first pose, where robots start
        self.hist: dict[int, np.ndarray] = {}

    def _grow(self, key, x_new, P_new, cross):
        n = self.x.size
        k = x_new.size
        self.x = np.r_[self.x, x_new]
        P = np.zeros((n + k, n + k))
        P[:n, :n] = self.P
        P[n:, :n] = cross
        P[:n, n:] = cross.T
        P[n:, n:] = P_new
        self.P = P
        self.index[key] = n

    def predict(self, robot: int, pid: int, u: np.ndarray) -> None:
        if robot not in self.live:  # a start from the first pose, uncorrelated
            x0, P0 = self.first
            F, G = models.compose_jacobians(x0, u)
            self._grow(("pose", robot), models.compose(x0, u), F @ P0 @ F.T + G @ Q @ G.T,
                       np.zeros((3, self.x.size)))
            self.live[robot] = pid
            return
        i = self.index[("pose", robot)]
        self.hist[self.live[robot]] = self.x[i:i + 3].copy()
        F, G = models.compose_jacobians(self.x[i:i + 3], u)
        self.x[i:i + 3] = models.compose(self.x[i:i + 3], u)
        Fb = np.eye(self.x.size)
        Fb[i:i + 3, i:i + 3] = F
        self.P = Fb @ self.P @ Fb.T
        self.P[i:i + 3, i:i + 3] += G @ Q @ G.T
        self.live[robot] = pid

    def _correct(self, H: np.ndarray, nu: np.ndarray, Rm: np.ndarray) -> None:
        S = H @ self.P @ H.T + Rm
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ nu
        self.P = self.P - K @ S @ K.T

    def observe(self, robot: int, lid: int, z: np.ndarray) -> None:
        i = self.index[("pose", robot)]
        xr = self.x[i:i + 3].copy()
        if ("lm", lid) not in self.index:
            G_x, G_z = models.inverse_observe_jacobians(xr, z)
            cross = G_x @ self.P[i:i + 3, :]
            self._grow(("lm", lid), models.inverse_observe(xr, z),
                       G_x @ self.P[i:i + 3, i:i + 3] @ G_x.T + G_z @ R @ G_z.T, cross)
            return
        j = self.index[("lm", lid)]
        H = np.zeros((2, self.x.size))
        H[:, i:i + 3], H[:, j:j + 2] = models.observe_jacobians(xr, self.x[j:j + 2])
        self._correct(H, models.innovation(z, models.observe(xr, self.x[j:j + 2])), R)

    def sight(self, a: int, b: int, z: np.ndarray) -> None:
        i, j = self.index[("pose", a)], self.index[("pose", b)]
        H = np.zeros((2, self.x.size))
        H[:, i:i + 3], H[:, j:j + 2] = models.observe_jacobians(self.x[i:i + 3], self.x[j:j + 2])
        self._correct(H, models.innovation(z, models.observe(self.x[i:i + 3], self.x[j:j + 2])), R)

    def trajectory(self) -> dict[int, np.ndarray]:
        out = dict(self.hist)
        for robot, pid in self.live.items():
            i = self.index[("pose", robot)]
            out[pid] = self.x[i:i + 3].copy()
        return out


def _stream(seed: int):
    """Three robots on circles through six landmarks, their frames interleaved: robot 1
    starts the run; robots 2 and 3 start from its first pose a few frames later. Each
    frame: (robot, pose id, odometry, landmark sightings, sightings of other robots)."""
    rng = np.random.default_rng(seed)
    lms = {k: rng.uniform(-6.0, 6.0, 2) for k in range(6)}
    starts = {1: np.zeros(3), 2: np.array([1.0, -2.0, 0.5]), 3: np.array([-1.5, 1.0, -1.0])}
    pose = {1: starts[1].copy()}
    frame = {1: 0}
    out = [(1, STRIDE, None, [], [])]
    for step in range(36):
        robot = 1 + step % 3
        if robot not in pose:  # its start, linked to robot 1's first pose
            u_true = models.between(starts[1], starts[robot])
            u = u_true + rng.normal(0.0, 0.01, 3)
            pose[robot], frame[robot] = starts[robot].copy(), 0
            odo = Odometry(STRIDE, robot * STRIDE, u, Q)
        else:
            u_true = np.array([0.5, 0.0, 0.2])
            u = u_true + rng.normal(0.0, np.sqrt(np.diag(Q)))
            pose[robot] = models.compose(pose[robot], u_true)
            frame[robot] += 1
            prev = robot * STRIDE + frame[robot] - 1
            odo = Odometry(prev, robot * STRIDE + frame[robot], u, Q)
        pid = robot * STRIDE + frame[robot]
        seen = [(k, models.observe(pose[robot], m) + rng.normal(0.0, np.sqrt(np.diag(R))))
                for k, m in lms.items() if rng.random() < 0.5]
        others = [(robot, other, models.observe(pose[robot], pose[other][:2])
                   + rng.normal(0.0, np.sqrt(np.diag(R))))
                  for other in pose if other != robot and step % 4 == 0]
        out.append((robot, pid, odo, seen, others))
    return out


def feed(backend, stream) -> DenseJointEkf:
    """Drive ``backend`` and a dense joint EKF through ``stream``; returns the reference."""
    ref = DenseJointEkf(STRIDE, np.zeros(3), PRIOR)
    backend.initialize(STRIDE, np.zeros(3), PRIOR)
    live = {1: STRIDE}
    for robot, pid, odo, seen, others in stream[1:]:
        backend.predict(odo, pid)
        ref.predict(robot, pid, odo.delta)
        live[robot] = pid
        backend.update([Observation(pid, k, z, R) for k, z in seen])
        for k, z in seen:
            ref.observe(robot, k, z)
        for a, b, z in others:
            backend.add_pose_sighting(PoseSighting(live[a], live[b], z, R))
            ref.sight(a, b, z)
    return ref


def _run(stream):
    ekf = EkfSlam(EkfSlamConfig(jacobians="standard", damped_update_nis=None))
    return ekf, feed(ekf, stream)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_several_robots_equal_the_dense_joint_ekf(seed):
    ekf, ref = _run(_stream(seed))
    est = ekf.estimate(with_covariances=True)
    want = ref.trajectory()
    assert sorted(int(i) for i in est.pose_ids) == sorted(want)
    for pid, wTb in zip(est.pose_ids.tolist(), est.wTb, strict=True):
        np.testing.assert_allclose(wTb, want[pid], atol=DENSE_TOL)
    for lid, m in zip(est.landmark_ids.tolist(), est.landmarks_w, strict=True):
        j = ref.index[("lm", lid)]
        np.testing.assert_allclose(m, ref.x[j:j + 2], atol=DENSE_TOL)
    # the whole joint covariance, the filter's state order mapped onto the reference's
    st = ekf._store
    order = {("pose", st_robot // STRIDE): i for st_robot, i in
             [(ekf._current_pose_id(), 0)] + [(p, st.parked_index(k)) for k, p in enumerate(st.parked_ids)]}
    order.update({("lm", lid): 3 + 2 * k for k, lid in enumerate(st.ids)})
    perm = np.empty(ref.x.size, int)
    for key, i in order.items():
        size = 3 if key[0] == "pose" else 2
        perm[ref.index[key]:ref.index[key] + size] = np.arange(i, i + size)
    np.testing.assert_allclose(ekf.state_covariance()[np.ix_(perm, perm)], ref.P, atol=DENSE_TOL)
    assert ekf.pose_sightings_used == sum(len(f[4]) for f in _stream(seed))


def test_one_robot_is_untouched_by_the_parking():
    """A single robot's run: no parked pose, the state is the course's ``[pose, landmarks]``."""
    stream = [f for f in _stream(3) if f[0] == 1]
    ekf = EkfSlam(EkfSlamConfig(jacobians="standard", damped_update_nis=None))
    ekf.initialize(STRIDE, np.zeros(3), PRIOR)
    for _, pid, odo, seen, _ in stream[1:]:
        ekf.predict(odo, pid)
        ekf.update([Observation(pid, k, z, R) for k, z in seen])
    assert ekf._store.parked_ids == [] and ekf.state_vector().size == 3 + 2 * ekf.num_landmarks


def test_a_sighting_of_a_pose_the_filter_no_longer_holds_is_refused():
    stream = _stream(0)[:8]
    ekf, _ = _run(stream)
    with pytest.raises(UnsupportedError, match="latest pose only"):
        ekf.add_pose_sighting(PoseSighting(STRIDE, stream[-1][1], np.array([1.0, 0.1]), R))


def test_a_robot_started_from_a_later_pose_is_refused():
    """Only the run's first pose starts another robot: the filter has dropped the others."""
    ekf, _ = _run(_stream(0)[:8])
    with pytest.raises(GraphSlamError, match="does not link the current pose"):
        ekf.predict(Odometry(STRIDE + 1, 9 * STRIDE, np.array([1.0, 0.0, 0.0]), Q), 9 * STRIDE)


def test_removing_a_landmark_keeps_the_parked_poses():
    """The pruning's marginalisation drops a landmark's rows and columns only."""
    from filters.ekf_slam_store import SlotStore

    st = SlotStore(4)
    st.start(np.array([1.0, 2.0, 0.3]), PRIOR)
    st.open_slot(7, np.array([4.0, 5.0]))
    st.park_and_start(100, np.array([-1.0, 0.5, 1.0]), 2 * PRIOR)
    st.open_slot(8, np.array([6.0, -1.0]))
    rng = np.random.default_rng(0)
    A = rng.normal(size=(st.n, st.n))
    st.P[:] = A @ A.T
    before_x, before_P = st.x.copy(), st.P.copy()
    st.remove_slots([0])
    keep = [0, 1, 2, 5, 6, 7, 8, 9]  # active pose, landmark 8, the parked pose
    np.testing.assert_array_equal(st.x, before_x[keep])
    np.testing.assert_array_equal(st.P, before_P[np.ix_(keep, keep)])
    assert st.ids == [8] and st.parked_index(0) == 5

"""Where the goal photo was taken, from SIFT matches and the current depth: a world-frame goal pose per frame
(:class:`GoalPoseEstimator`) and a running estimate kept over the episode (:class:`GoalTracker`).

One frame: SIFT keypoints (OpenCV) on the goal photo (once per episode) and the current RGB frame, Lowe's
ratio test both ways (a mutual match); each matched current keypoint becomes a 3-D point in the current camera
frame from the current z-depth (:func:`nue.sim.camera.pixel_directions` times the pixel's depth; keypoints on a
depth edge are left out). Geometric verification: PnP-RANSAC (``cv2.solvePnPRansac``) finds the goal camera that
sees those points at the goal keypoints' pixels, refined on its inliers (Levenberg-Marquardt); it is rerun on the
matches outside the consensus (up to ``hypotheses`` poses), because a repeated texture can outvote the unique
content. A pose is plausible when the goal camera is level and at the current camera's height (every camera of
the task is) and at most ``max_range`` away; the plausible poses are scored photometrically (the current frame
moved by its depth into the goal view against the goal photo, :meth:`GoalPoseEstimator.agreement`), and the best
is kept if it has ``min_inliers`` inliers, agrees at least ``min_agreement`` and clearly more than any other
pose elsewhere. Its camera centre goes to the world through the robot's pose
(:func:`nue.sim.camera.world_from_camera`).

Pixel convention: OpenCV puts a pixel's centre at integer coordinates, the camera model (``nue.sim.camera``)
at ``+0.5``; keypoints are shifted by 0.5 px so the task's intrinsics (``cx = W / 2``) hold unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from nue.sim.camera import pixel_directions, world_from_camera
from nue.sim.task import CameraConfig


@dataclass(frozen=True)
class GoalPoseConfig:
    """Matching the goal photo to the current frame and accepting the pose it gives (pixels, metres, degrees)."""

    contrast_threshold: float = 0.02
    """SIFT's contrast threshold (OpenCV's default is 0.04; the 180 x 240 frames give ~2x more keypoints at 0.02)."""
    ratio: float = 0.8
    """Lowe's ratio test: a match is kept when its descriptor distance is below this times the second best."""
    min_matches: int = 8
    """Fewer ratio-test matches with valid depth than this: no PnP is tried."""
    max_depth: float = 8.0
    """Keypoints whose depth is 0 (no surface) or beyond this are not used, metres."""
    depth_edge: float = 0.05
    """A keypoint is on a depth edge (left out) when its 3 x 3 depth neighbourhood spans more than this fraction
    of its depth (its 3-D point could belong to either side)."""
    reprojection_error: float = 3.0
    """PnP-RANSAC inlier threshold, pixels in the goal photo."""
    ransac_iterations: int = 300
    """PnP-RANSAC iterations."""
    min_inliers: int = 12
    """Fewer PnP inliers than this: no estimate from the frame."""
    hypotheses: int = 3
    """PnP-RANSAC is run up to this many times, each on the matches outside the earlier consensus sets: our houses
    tile wall, floor and wood textures every metre, so a pose shifted by one repeat can fit many matches and only
    the unique content (pictures, furniture edges, doorways) supports the right one."""
    min_rival_inliers: int = 6
    """A hypothesis needs at least this many inliers to be considered."""
    consistent_centres: float = 0.3
    """Two hypotheses whose camera centres are closer than this are the same pose, metres."""
    check_stride: int = 3
    """The photometric check (:meth:`GoalPoseEstimator.agreement`) samples every this-many-th pixel per axis."""
    min_agreement: float = 0.75
    """Least normalised cross-correlation between the current frame moved into the goal view and the goal photo
    (right poses measured 0.8-0.99, poses off by a texture repeat mostly below 0.6)."""
    agreement_margin: float = 0.15
    """The most agreeing plausible hypothesis wins only if every other one more than ``consistent_centres`` away
    agrees less by this margin; else the frame is ``ambiguous``."""
    max_tilt_deg: float = 10.0
    """The goal camera's down axis must be within this angle of the current camera's (both are level), degrees."""
    max_height_error: float = 0.25
    """The goal camera's centre must be within this of the current camera's height (both at the mount height), metres."""
    max_range: float = 6.0
    """The goal camera must be at most this far from the current camera (horizontally), metres."""


@dataclass(frozen=True)
class GoalMeasurement:
    """The goal pose one frame gives: where the goal photo was taken, in world coordinates."""

    xy: np.ndarray
    """(2,) world (x, y) of the goal camera, metres."""
    yaw: float
    """Heading of the goal camera, radians (counter-clockwise from +x)."""
    inliers: int
    """PnP-RANSAC inliers."""
    matches: int
    """Ratio-test matches with valid depth that went into PnP."""
    distance: float
    """Horizontal distance from the current camera to the goal camera, metres."""
    reprojection: float
    """Mean reprojection error of the inliers after refinement, pixels."""
    agreement: float
    """Photometric agreement of the pose (normalised cross-correlation, :meth:`GoalPoseEstimator.agreement`)."""


@dataclass
class MatchReport:
    """What the last :meth:`GoalPoseEstimator.estimate` call found (also when it gave no measurement)."""

    matches: int = 0
    """Ratio-test matches with valid depth."""
    inliers: int = 0
    """PnP-RANSAC inliers (0 when PnP was not tried or failed)."""
    agreement: float = float("nan")
    """Photometric agreement of the PnP pose (:meth:`GoalPoseEstimator.agreement`), NaN when not reached."""
    reason: str = ""
    """Why no measurement: ``no_features``, ``few_matches``, ``pnp_failed``, ``few_inliers``, ``tilted``,
    ``height``, ``range``, ``ambiguous``, ``disagrees``; '' when a measurement was made."""


class GoalPoseEstimator:
    """Goal photo + current RGB-D frame + robot pose -> :class:`GoalMeasurement` or None.

    ``camera``: the task's camera (intrinsics and mount height; goal photo and frames share it);
    ``floor_z``: floor height of the robot's floor, metres. Call :meth:`set_goal` once per episode.
    """

    def __init__(self, camera: CameraConfig, floor_z: float = 0.0, config: GoalPoseConfig = GoalPoseConfig()):
        self.camera, self.floor_z, self.config = camera, float(floor_z), config
        self.sift = cv2.SIFT_create(contrastThreshold=config.contrast_threshold)
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        self.K = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
        self._dirs = pixel_directions(camera)  # (H, W, 3) unit-z ray directions of the pixel centres
        self.goal_uv: np.ndarray = np.zeros((0, 2))
        self.goal_des: np.ndarray | None = None
        self._goal_gray = np.zeros((camera.height, camera.width))
        self.report = MatchReport()

    def features(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """SIFT keypoints of an (H, W, 3) uint8 image: pixel coordinates (K, 2) in the camera model's convention
        (centre of pixel (row v, col u) at (u + 0.5, v + 0.5)) and descriptors (K, 128) float32 (None if K = 0)."""
        gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
        # detection may run on several threads, which can change the keypoints' order (and so RANSAC's samples):
        # a fixed order keeps the estimates repeatable
        kps = sorted(self.sift.detect(gray, None), key=lambda k: (k.pt[1], k.pt[0], k.size, k.angle, k.octave))
        kps, des = self.sift.compute(gray, kps)
        uv = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2) + 0.5
        return uv, des

    def set_goal(self, goal_rgb: np.ndarray) -> None:
        """Keypoints of the goal photo (H, W, 3) uint8, kept for the episode."""
        self.goal_uv, self.goal_des = self.features(goal_rgb)
        self._goal_gray = cv2.cvtColor(np.ascontiguousarray(goal_rgb), cv2.COLOR_RGB2GRAY).astype(np.float64)

    def match(self, des: np.ndarray | None) -> np.ndarray:
        """(N, 2) index pairs (current keypoint, goal keypoint) passing Lowe's ratio test both ways (a goal keypoint
        whose best current match is not clearly better than its second, as on a repeated texture, is left out)."""
        if des is None or self.goal_des is None or len(des) < 2 or len(self.goal_des) < 2:
            return np.zeros((0, 2), dtype=np.int64)
        ratio = self.config.ratio
        forward = {a.queryIdx: a.trainIdx for a, b in _pairs(self.matcher.knnMatch(des, self.goal_des, k=2))
                   if a.distance < ratio * b.distance}
        backward = {a.queryIdx: a.trainIdx for a, b in _pairs(self.matcher.knnMatch(self.goal_des, des, k=2))
                    if a.distance < ratio * b.distance}
        pairs = [(q, g) for q, g in forward.items() if backward.get(g) == q]
        return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)

    def points(self, uv: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame 3-D points (K', 3) of keypoints ``uv`` (K, 2) from z-depth (H, W) metres, and the indices
        (K',) of the keypoints they belong to (those with depth in (0, max_depth] off depth edges)."""
        h, w = depth.shape
        col = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, h - 1)
        z = depth[row, col]
        r3 = np.clip(row[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1]), 0, h - 1)
        c3 = np.clip(col[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1]), 0, w - 1)
        patch = depth[r3, c3]
        flat = (patch.max(axis=1) - patch.min(axis=1)) <= self.config.depth_edge * z
        ok = np.flatnonzero((z > 0) & (z <= self.config.max_depth) & flat & np.isfinite(z))
        return self._dirs[row[ok], col[ok]] * z[ok, None], ok

    def _ransac(self, obj: np.ndarray, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """PnP-RANSAC of 3-D points ``obj`` (N, 3) (current camera frame) seen at goal pixels ``img`` (N, 2):
        ``(rvec, tvec, inlier indices)`` or None."""
        cfg = self.config
        if len(obj) < 4:
            return None
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            obj, img, self.K, None, iterationsCount=cfg.ransac_iterations, reprojectionError=cfg.reprojection_error,
            confidence=0.999, flags=cv2.SOLVEPNP_AP3P)
        return (rvec, tvec, inl.ravel()) if found and inl is not None else None

    def agreement(self, rgb: np.ndarray, depth: np.ndarray, rot: np.ndarray, tvec: np.ndarray) -> tuple[float, float]:
        """Photometric check of a pose: every ``stride``-th pixel of the current frame, moved by its depth into the
        goal camera (``x_goal = rot x + tvec``), is compared with the goal photo where it lands. Returns the
        normalised cross-correlation of the grey levels (-1..1; the renderer shades surfaces the same from every
        viewpoint, so a right pose gives ~1) and the fraction of the goal photo's sampled pixels covered. Catches
        poses that fit a repeated texture (two cabinet faces with the same wood) but not the rest of the view."""
        cam, k = self.camera, self.config.check_stride
        z = depth[k // 2::k, k // 2::k]
        cur = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)[k // 2::k, k // 2::k].astype(np.float64)
        pts = self._dirs[k // 2::k, k // 2::k] * z[..., None]
        valid = z > 0
        pg = pts[valid] @ rot.T + np.asarray(tvec, dtype=np.float64).ravel()
        front = pg[:, 2] > cam.near
        u = cam.fx * pg[front, 0] / pg[front, 2] + cam.cx
        v = cam.fy * pg[front, 1] / pg[front, 2] + cam.cy
        inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        if inside.sum() < 20:
            return 0.0, 0.0
        # a z-buffer at the sampling resolution: per goal cell only the nearest point (the one the goal camera sees)
        cell = (v[inside].astype(np.int64) // k) * (cam.width // k + 1) + u[inside].astype(np.int64) // k
        order = np.lexsort((pg[front][inside, 2], cell))
        first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]]
        a = cur[valid][front][inside][first]
        b = self._goal_gray[v[inside][first].astype(np.int64), u[inside][first].astype(np.int64)]
        a, b = a - a.mean(), b - b.mean()
        ncc = float((a * b).sum() / max(math.sqrt(float((a * a).sum() * (b * b).sum())), 1e-9))
        covered = np.zeros((cam.height // k + 1, cam.width // k + 1), dtype=bool)
        covered.ravel()[cell] = True
        return ncc, float(covered.mean())

    def _hypotheses(self, obj: np.ndarray, img: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Up to ``hypotheses`` PnP-RANSAC poses, each on the matches outside the consensus sets before it, with at
        least ``min_rival_inliers`` inliers: ``(rvec, tvec, inlier indices into obj)``, most inliers first."""
        cfg = self.config
        idx = np.arange(len(obj))
        out: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        while len(out) < cfg.hypotheses and len(idx) >= max(cfg.min_rival_inliers, 4):
            solved = self._ransac(obj[idx], img[idx])
            if solved is None or len(solved[2]) < cfg.min_rival_inliers:
                break
            out.append((solved[0], solved[1], idx[solved[2]]))
            idx = np.delete(idx, solved[2])
        return out

    def _implausible(self, rot: np.ndarray, centre: np.ndarray) -> str:
        """Why a goal camera (rotation current -> goal, centre (3,) in the current camera frame) cannot be the
        goal camera ('' if it can): ``tilted``, ``height`` or ``range``."""
        cfg = self.config
        if math.degrees(math.acos(float(np.clip(rot[1, 1], -1.0, 1.0)))) > cfg.max_tilt_deg:  # goal's down axis vs ours
            return "tilted"
        if abs(centre[1]) > cfg.max_height_error:
            return "height"
        if math.hypot(centre[0], centre[2]) > cfg.max_range:
            return "range"
        return ""

    def estimate(self, rgb: np.ndarray, depth: np.ndarray, pose) -> GoalMeasurement | None:
        """The goal pose seen from the current frame: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W[, 1]) z-depth
        metres, robot ``pose`` (x, y, yaw). None when the frame gives no plausible pose (see :attr:`report`)."""
        cfg = self.config
        self.report = rep = MatchReport()
        uv, des = self.features(rgb)
        if des is None or self.goal_des is None:
            rep.reason = "no_features"
            return None
        pairs = self.match(des)
        depth = np.asarray(depth, dtype=np.float64).reshape(self.camera.height, self.camera.width)
        obj, ok = self.points(uv[pairs[:, 0]], depth) if len(pairs) else (np.zeros((0, 3)), np.zeros(0, np.int64))
        img = self.goal_uv[pairs[ok, 1]] if len(pairs) else np.zeros((0, 2))
        rep.matches = len(ok)
        if len(ok) < max(cfg.min_matches, 4):
            rep.reason = "few_matches"
            return None
        hyps = self._hypotheses(obj, img)
        if not hyps:
            rep.reason = "pnp_failed"
            return None
        rep.inliers = len(hyps[0][2])
        scored = []  # (agreement, inliers, rvec, tvec, centre) of the plausible hypotheses
        reason = ""
        for rvec, tvec, inl in hyps:
            if len(inl) >= cfg.min_inliers:
                rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], self.K, None, rvec, tvec)
            rot, _ = cv2.Rodrigues(rvec)  # current camera frame -> goal camera frame
            centre = _centre(rvec, tvec)
            why = self._implausible(rot, centre)
            if why:
                reason = reason or why
                continue
            scored.append((self.agreement(rgb, depth, rot, tvec)[0], inl, rvec, tvec, centre))
        if not scored:
            rep.reason = reason
            return None
        scored.sort(key=lambda h: -h[0])
        ncc, inl, rvec, tvec, centre = scored[0]
        rep.agreement, rep.inliers = ncc, len(inl)
        if len(inl) < cfg.min_inliers:
            rep.reason = "few_inliers"
            return None
        if ncc < cfg.min_agreement:
            rep.reason = "disagrees"
            return None
        if any(np.linalg.norm(c - centre) > cfg.consistent_centres and a > ncc - cfg.agreement_margin
               for a, _, _, _, c in scored[1:]):
            rep.reason = "ambiguous"
            return None
        proj, _ = cv2.projectPoints(obj[inl], rvec, tvec, self.K, None)
        reproj = float(np.linalg.norm(proj.reshape(-1, 2) - img[inl], axis=1).mean())
        rot, _ = cv2.Rodrigues(rvec)
        distance = float(math.hypot(centre[0], centre[2]))
        m = world_from_camera(pose, self.camera, self.floor_z)
        xy = (m[:3, :3] @ centre + m[:3, 3])[:2]
        axis = m[:3, :3] @ rot[2]  # the goal camera's optical axis in the world
        return GoalMeasurement(xy=xy, yaw=math.atan2(axis[1], axis[0]), inliers=len(inl), matches=len(ok),
                               distance=distance, reprojection=reproj, agreement=float(ncc))


def _centre(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(3,) centre of the camera of a PnP pose (object frame -> camera: ``x_cam = R x + t``) in the object frame,
    ``-R^T t``: here the goal camera in the current camera frame (x right, y down, z ahead), metres."""
    rot, _ = cv2.Rodrigues(rvec)
    return -rot.T @ np.asarray(tvec, dtype=np.float64).ravel()


def _pairs(knn) -> list:
    """The (best, second best) pairs of a ``knnMatch(..., k=2)`` result (entries with one match dropped)."""
    return [m for m in knn if len(m) == 2]


@dataclass(frozen=True)
class TrackerConfig:
    """How measurements make, refine and drop the running goal estimate (metres)."""

    accept_inliers: int = 20
    """The estimate is accepted (the last mile starts) once its consistent measurements sum to this many inliers:
    one strong frame, or two weaker ones that agree."""
    consistency_radius: float = 0.75
    """A measurement within this of the estimate refines it; farther, it is a strike against it."""
    max_strikes: int = 2
    """This many inconsistent measurements in a row drop the estimate; the last one starts a new candidate."""
    reject_radius: float = 0.6
    """Measurements within this of a place where a dropped estimate was disproved (reached without success,
    unreachable) are ignored for the rest of the episode."""


class GoalTracker:
    """The running goal estimate in world coordinates: the inlier-weighted mean of consistent measurements.

    States: no estimate -> candidate (not enough inliers yet) -> accepted; :meth:`drop` (by the tracker on
    ``max_strikes`` inconsistent measurements, or by the controller) returns to no estimate.
    """

    def __init__(self, config: TrackerConfig = TrackerConfig()):
        self.config = config
        self.rejected: list[np.ndarray] = []
        self.clear()

    def clear(self) -> None:
        """No estimate (the disproved places stay)."""
        self.xy: np.ndarray | None = None
        """(2,) world (x, y) of the estimate, metres, or None."""
        self.weight = 0.0
        """Sum of the inliers of the measurements in the estimate."""
        self.count = 0
        """Measurements in the estimate."""
        self.strikes = 0
        self.accepted = False

    def update(self, m: GoalMeasurement) -> str:
        """Take one measurement; returns what it did: ``ignored`` (near a disproved place), ``new``, ``refined``,
        ``accepted`` (refined or new and now accepted), ``strike`` or ``dropped`` (then a new candidate)."""
        cfg = self.config
        if any(np.linalg.norm(m.xy - r) <= cfg.reject_radius for r in self.rejected):
            return "ignored"
        was = self.accepted
        if self.xy is None:
            self.xy, self.weight, self.count, self.strikes = m.xy.astype(np.float64), float(m.inliers), 1, 0
            event = "new"
        elif np.linalg.norm(m.xy - self.xy) <= cfg.consistency_radius:
            w = float(m.inliers)
            self.xy = (self.weight * self.xy + w * m.xy) / (self.weight + w)
            self.weight += w
            self.count += 1
            self.strikes = 0
            event = "refined"
        else:
            self.strikes += 1
            if self.strikes < cfg.max_strikes:
                return "strike"
            self.clear()
            self.update(m)
            return "dropped"
        self.accepted = self.weight >= cfg.accept_inliers
        return "accepted" if self.accepted and not was else event

    def drop(self, disproved: bool) -> None:
        """Forget the estimate; ``disproved``: its place is ignored from now on (see ``reject_radius``)."""
        if disproved and self.xy is not None:
            self.rejected.append(self.xy.copy())
        self.clear()

"""The head-pose convention, in one place: axes, rotations and the point the head turns about.

Face axes are right-handed: x toward the face's own left, y up, z toward the
camera; the tracker's image axes (x right, y down, z away) map onto them by
:func:`image_to_face_axes`. The stream sends the head's rotation as a rotation
vector rx, ry, rz in degrees (axis times angle, the head's orientation as the
camera sees it) and its translation tx, ty, tz in base-face units; the head
turns about :func:`head_pivot`, HEAD_DEPTH behind the centre of the face's
bounding box, so that a turn moves the face as a skull does and not about the
nose. The sender measures the pose (sender/pose.py), the deformer applies it to
the mesh (codec/model/deform.py) and the whole picture places the mesh with it
(codec/render/picture.py); all three read these definitions.
"""

import numpy as np

HEAD_DEPTH = 0.6  # the head turns about a point this far behind the face's bounding-box centre


def image_to_face_axes(landmarks: np.ndarray) -> np.ndarray:
    """(n, 3) tracker landmarks (x right, y down, z away from the camera) -> x right, y up, z toward the camera."""
    return np.asarray(landmarks, dtype=np.float64) * np.array([1.0, -1.0, -1.0])


def head_pivot(vertices: np.ndarray) -> np.ndarray:
    """(3,) the point the head turns about: HEAD_DEPTH behind the centre of the face's bounding box."""
    v = np.asarray(vertices, dtype=np.float64)
    return 0.5 * (v.min(axis=0) + v.max(axis=0)) - [0.0, 0.0, HEAD_DEPTH]


def rotation_matrix(axis: np.ndarray, theta_deg: float) -> np.ndarray:
    """(3, 3) right-handed rotation by theta_deg about the unit vector axis (Rodrigues)."""
    t = np.radians(theta_deg)
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(t) * k + (1.0 - np.cos(t)) * (k @ k)


def rotation_from_vector(rvec_deg: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a (3,) rotation vector in degrees (axis times angle), as the stream sends the head's."""
    rvec = np.asarray(rvec_deg, dtype=np.float64)
    angle = float(np.linalg.norm(rvec))
    return rotation_matrix(rvec / angle, angle) if angle > 0 else np.eye(3)


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """(3,) rotation vector in degrees of a (3, 3) rotation: :func:`rotation_from_vector` inverted."""
    import cv2

    rvec, _ = cv2.Rodrigues(np.ascontiguousarray(rotation))
    return np.degrees(rvec.ravel())

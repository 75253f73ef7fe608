"""Head pose: the similarity fit recovers a known rotation, scale and shift."""

import cv2
import numpy as np

from facedeform.codec.model.head_pose import image_to_face_axes
from facedeform.sender.pose import fit_pose


def test_fit_recovers_a_similarity():
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(30, 3))
    rotation, _ = cv2.Rodrigues(np.array([0.2, -0.4, 0.1]))
    observed = (reference @ rotation.T) * 3.0 + [5.0, -2.0, 1.0]
    pose = fit_pose(observed, reference)
    np.testing.assert_allclose(pose.apply(observed), reference, atol=1e-9)
    np.testing.assert_allclose(pose.rotation, rotation.T, atol=1e-9)
    np.testing.assert_allclose(pose.scale, 1 / 3.0)
    np.testing.assert_allclose(np.radians(pose.head_rotation_vector()), [0.2, -0.4, 0.1], atol=1e-9)


def test_fit_never_reflects():
    rng = np.random.default_rng(4)
    reference = rng.normal(size=(20, 3))
    pose = fit_pose(reference * [-1, 1, 1], reference)
    np.testing.assert_allclose(np.linalg.det(pose.rotation), 1.0)


def test_image_axes_flip_y_and_z():
    np.testing.assert_array_equal(image_to_face_axes(np.array([[1.0, 2.0, 3.0]])), [[1.0, -2.0, -3.0]])

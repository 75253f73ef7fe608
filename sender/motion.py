"""Learning a person's motion basis from a clip of them talking (fd-enroll).

The clip is analysed exactly as fd-send will analyse a call with this face
model (same tracker, rest face, paper fit) but unsmoothed, so the residuals are
the motion and not the filter's lag. The whole face's displacement from the
rest face, or what the paper's 13 parameters leave over of it, becomes the
basis (codec/model/motion_basis.py).

Whole face, because a basis over part of the mesh moves that part past the
still vertices around it: the dev clips' nose bottom rises with the upper lip,
and a basis over the lower face alone (the paper's regions) turned the small
triangles at its rim over in up to 84 % of a clip's frames, so that the
receiver's fold guard drew the whole mouth scaled back (its opening swung 0.59
times the speaker's on one clip). Over every vertex the basis has no rim: the
same clips fold in 0-9 % of frames, the mouth swings 0.85-1.03 times, and the
patterns also carry the speaker's own blinks and brows when the clip shows them.
"""

from collections.abc import Iterable
from dataclasses import replace

import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.model.motion_basis import MotionBasis, learn_basis
from facedeform.sender.analysis import FaceAnalyser, Smoothing

#: Frames with a face needed per pattern. Held out on the dev clips (a basis learned from each
#: clip's first half, measured on the second), 4 beat 8 on the shortest clip (9 patterns instead
#: of 4: error 0.19 instead of 0.30 at level 3), a little on two clips that had 10 and 11, and
#: changed nothing where 8 already gave 12.
FRAMES_PER_PATTERN = 4


def residuals(frames: Iterable[np.ndarray], tracker, face: BaseFace, fps: float, over: str = "rest",
              neutral: int | None = None, on_frame=None) -> tuple[np.ndarray, np.ndarray]:
    """((n, k, 3) displacements from the rest face, or with ``over="paper"`` residuals of the paper
    fit, of all k vertices, (k,) their indices), for the n frames with a face; ``neutral``: the rest
    frame's index (default: chosen as fd-send does); ``on_frame(count)`` after each frame (progress)."""
    # the residuals need neither where the head is in a reference picture nor the frame's motion
    analyser = FaceAnalyser(tracker, replace(face, picture=None), fps, "paper", calibration_frames=round(fps),
                            neutral=neutral, smoothing=Smoothing(0.0))
    deformer = Deformer(face)
    vertices = np.arange(len(face.vertices))
    out = []
    for count, result in enumerate(analyser.run(frames), 1):
        if result.target is not None:
            params = result.params[:13] if over == "paper" else np.zeros(13)
            out.append(result.target - deformer.deform(params))
        if on_frame is not None:
            on_frame(count)
    return (np.stack(out) if out else np.zeros((0, len(vertices), 3))), vertices


def learn_motion(residual: np.ndarray, vertices: np.ndarray, components: int,
                 over: str = "rest") -> MotionBasis | None:
    """The basis of ``components`` patterns, or of as many as the frames allow (FRAMES_PER_PATTERN
    each), or None when they allow none: on the dev clips every pattern up to the limit pays its
    bits, so a short clip gets fewer patterns rather than none."""
    components = min(components, len(residual) // FRAMES_PER_PATTERN)
    if components < 1:
        return None
    return learn_basis(residual, vertices, components, over)

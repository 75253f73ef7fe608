"""Limits that several stages must agree on, in one place."""

#: Pixels of any picture's width or height: a source named in a stream header, a rendered
#: output (``--size``, ``facedeform.decode``), a face model's reference picture. Checked where
#: each is parsed, so a stream cannot ask a receiver for more than it would draw on request.
MAX_SIDE = 4096

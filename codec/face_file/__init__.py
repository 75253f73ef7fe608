"""The face file: a person's face model as bytes, shared before the call or carried in the stream."""

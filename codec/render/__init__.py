"""Drawing a deformed face: cameras, the software rasteriser, the whole picture and the picture layer's video."""

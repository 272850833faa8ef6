"""Offscreen rendering of pursuit episodes: frames, overlays, captions, videos and still images.

`renderer.SceneRenderer` draws drone poses in a layout's scene (EGL or OSMesa, `gl.py`);
`overlays` adds what explains a chase; `caption` the text band; `video` writes mp4/gif/PNG
atomically; `episodes.run_episodes` plays a policy and feeds every recorder.
"""

"""The synthetic multi-season survey world: the project's test bed with exact ground truth.

Modules, in the order the data flows:
- `noise`: deterministic fractal noise (the texture and relief building block).
- `world`: the world of one seed: terrain, ground cover, per-season albedo; `objects` places its objects.
- `scene`: `build_scene` stamps the objects present in a session into a digital surface model (DSM), an
  object-id raster and an albedo raster; `visible_top_centres` is the truth the cameras see of each object.
- `appearance`: seasons, sun, the per-session lighting raster (Lambert shading + cast shadows) and the camera
  pipeline (exposure, white balance, vignetting, blur, noise, JPEG).
- `flights`: lawnmower and free-form paths, their transforms (shift, reverse, rotate), attitude jitter and the
  EKF-like pose noise.
- `render`: perspective ray marching of the DSM for one camera (image radiance + per-pixel object ids).

`sosmatch.workflows.synth.run` ties them together and writes a session directory.
"""

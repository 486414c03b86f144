"""Real captures in the Spring-Gaus layout: a simulated capture and the tools a real one needs.

The Spring-Gaus real-capture layout (the official loader `lib/datasets/real_capture.py`) holds a
static scan (photos, masks, COLMAP cameras) and a dynamic capture from three calibrated video
cameras (`layout` names every file). Modules (import them directly; this package imports nothing):

- `layout`: the file names of the layout and the three hard-coded camera names.
- `similarity`: `Similarity` (X' = s R X + t) and moving OpenCV cameras between frames.
- `colmap`: COLMAP binary cameras.bin / images.bin / points3D.bin, written and read.
- `board`: the checkerboard's geometry and colour convention, and its analytic images.
- `calibrate`: OpenCV calibration of a video camera from checkerboard images; cameras_calib.json.
- `masks`: object masks by background subtraction against a clean plate.
- `config`: `RealCaptureSimConfig` (group key `realcap`), the simulated capture's sizes.
- `scene`: the Mitsuba scenes of the simulation (object on a table) and the camera pipeline
  (exposure, white balance, sensor noise, sRGB, JPEG).
- `simulate`: `simulate_real_capture(out_dir, cfg, seed)`, a complete simulated capture.
"""

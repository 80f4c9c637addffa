"""
Calibrating the rig, and the calibration files every node loads.

- ``files``: camera_calibration YAML (the format ROS ``camera_calibration`` writes and
  ``camera_info_manager`` reads): parse, validate, write, check that two files are a pair;
- ``targets``: calibration targets and their detection in 80x60 thermal images;
- ``target_refinement``: sub-pixel target features by fitting a blurred, pixel-integrated model;
- ``stereo``: mono and stereo calibration from target detections (``st-stereo calibrate``,
  ``st_stereo/tools/calibrate.py``, reads the images and writes the files).

Rectification with a calibration is ``st_stereo.core.rectification``.
"""

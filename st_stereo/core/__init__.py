"""
The ST algorithm: phase-congruency features, rough matching, POC sub-pixel refinement.

Pure numpy / scipy / OpenCV; no ROS import anywhere in this package.
"""

from st_stereo.core.config import STConfig
from st_stereo.core.matcher import MatchResult, StereoMatcher
from st_stereo.core.triangulation import StereoModel, triangulate

__all__ = ['MatchResult', 'STConfig', 'StereoMatcher', 'StereoModel', 'triangulate']

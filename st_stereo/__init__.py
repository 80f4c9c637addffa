"""st_stereo: sub-pixel thermal stereo (ST) for a ceiling rig of two FLIR Lepton 2 cameras."""

__version__ = '0.1.0'

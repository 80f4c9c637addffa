"""
The FLIR Lepton 2 layer: VoSPI packets, frame assembly, readers, CCI, transports, simulator.

No ROS import: the driver node only wraps it. ``LeptonReader`` turns any transport (SPI,
simulator, capture replay) into intact unique frames; ``PairSynchronizer`` pairs two cameras.
"""

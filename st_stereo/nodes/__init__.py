"""Thin rclpy nodes: they convert messages, hold parameters and call the core and lepton."""

"""Numeric core: model, sensors, decoupling, controllers, modes, engine. Never imports rclpy."""

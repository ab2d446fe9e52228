"""Placeholder so that setup.py's launch/ glob has a file; replaced by the real graph launch."""

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    """An empty launch description (placeholder)."""
    return LaunchDescription([])

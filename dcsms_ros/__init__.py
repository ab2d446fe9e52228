"""dcsms_ros: simulate, control and analyse a dual-stage cascade spring-mass isolation system."""

__version__ = "0.1.0"

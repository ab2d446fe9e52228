"""ROS 2 infrastructure shared by the nodes: context, host, hot loop, parameters, QoS."""

"""ROS adapters shared by the nodes and tools: parameter schema, message conversions,
diagnostics and the node runner.
"""

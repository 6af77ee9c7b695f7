"""ROS networking: the XML-RPC codec, clients and HTTP server, TCPROS, an in-process node's slave API, rosout.

Nothing here knows about launch files or node processes.
"""

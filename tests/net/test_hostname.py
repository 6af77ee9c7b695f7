"""Where this machine's ROS servers listen: the master, by the environment; a server named by its host, by that
name."""

from launcher.net.hostname import bind_address, listen_address


def test_a_server_named_by_a_loopback_name_listens_on_loopback_only():
    assert listen_address("127.0.0.1") == "127.0.0.1"
    assert listen_address("127.0.1.1") == "127.0.1.1"
    assert listen_address("localhost") == "127.0.0.1"
    assert listen_address("::1") == "::1"
    assert listen_address("robot.example") == "0.0.0.0"
    assert listen_address("10.0.0.5") == "0.0.0.0"


def test_the_master_listens_on_loopback_only_when_ros_ip_or_ros_hostname_is_a_loopback_name():
    assert bind_address({"ROS_IP": "127.0.0.1"}) == "127.0.0.1"
    assert bind_address({"ROS_HOSTNAME": "localhost", "ROS_IP": "10.0.0.5"}) == "127.0.0.1"
    assert bind_address({"ROS_HOSTNAME": "localhost", "ROS_IPV6": "on"}) == "::1"
    assert bind_address({"ROS_IP": "10.0.0.5"}) == "0.0.0.0"
    assert bind_address({}) == "0.0.0.0"
    assert bind_address({"ROS_IPV6": "on"}) == "::"

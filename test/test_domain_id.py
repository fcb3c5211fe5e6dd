"""The demo's ROS_DOMAIN_ID picker: ids with DDS participants or another run's lock are skipped."""

from __future__ import annotations

import os
import socket

import pytest

from ekf_localization.tools import domain_id


def test_ports_follow_the_rtps_mapping():
    assert domain_id.domain_ports(0)[0] == 7400
    assert domain_id.domain_ports(1)[0] == 7650
    # domain 101's discovery port and 50 participants' unicast ports stay below Linux's ephemeral ports
    assert domain_id.domain_ports(101)[0] + 11 + 2 * 50 < 32768


def test_bound_udp_ports_sees_a_socket_of_this_process():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        if not os.path.exists("/proc/net/udp"):
            pytest.skip("no /proc/net/udp here")
        assert port in domain_id.bound_udp_ports()


def test_skips_domains_with_participants(tmp_path):
    busy = {7400 + 250 * 3 + 10, 7400 + 250 * 4}  # a unicast port of domain 3, discovery of 4
    d, fd = domain_id.pick_free_domain(3, 6, lock_dir=tmp_path, scan=lambda: busy)
    try:
        assert d == 5
    finally:
        os.close(fd)


def test_two_runs_get_different_domains_and_a_lock_is_released_on_close(tmp_path):
    first, fd1 = domain_id.pick_free_domain(7, 9, lock_dir=tmp_path, scan=set)
    second, fd2 = domain_id.pick_free_domain(7, 9, lock_dir=tmp_path, scan=set)
    assert (first, second) == (7, 8)
    os.close(fd1)
    again, fd3 = domain_id.pick_free_domain(7, 9, lock_dir=tmp_path, scan=set)
    assert again == 7
    os.close(fd2)
    os.close(fd3)


def test_full_range_says_what_to_do(tmp_path):
    fd = domain_id.try_lock(2, tmp_path)
    try:
        with pytest.raises(RuntimeError, match="ROS_DOMAIN_ID"):
            domain_id.pick_free_domain(2, 2, lock_dir=tmp_path, scan=set)
    finally:
        os.close(fd)


def test_range_from_the_environment():
    assert domain_id.domain_range({}) == domain_id.DEFAULT_RANGE
    assert domain_id.domain_range({"EKF_DEMO_DOMAINS": "26:40"}) == (26, 40)
    with pytest.raises(ValueError):
        domain_id.domain_range({"EKF_DEMO_DOMAINS": "40"})
    with pytest.raises(ValueError):
        domain_id.domain_range({"EKF_DEMO_DOMAINS": "9:3"})

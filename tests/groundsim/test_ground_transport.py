"""UGV states over Zenoh (`skyherd/ugv/<id>/state`) between two real sessions on loopback."""

import socket
import time

import numpy as np
import pytest

from skyherd.groundsim.transport import UGVStatePublisher, UGVStateSubscriber
from skyherd.groundsim.ugv import UGVStates
from skyherd.perception.transport import open_session, publisher_params, subscriber_params


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ugv_states_over_zenoh():
    port = free_port()
    a = open_session(publisher_params(port))
    b = open_session(subscriber_params(port=port))
    try:
        sub = UGVStateSubscriber(b)
        pub = UGVStatePublisher(a, 3)
        junk = a.declare_publisher("skyherd/ugv/9/state")
        probe = a.declare_publisher("skyherd/ugv/0/state")
        deadline = time.monotonic() + 30  # the sessions meet, then the subscriber is matched
        while not (junk.matching_status.matching and probe.matching_status.matching):
            assert time.monotonic() < deadline, "the subscriber never matched"
            time.sleep(0.02)
        st = UGVStates(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), np.array([0.1, 0.2, 0.3]),
                       np.array([1.0, 2.0, 3.0]), np.array([False, True, False]))  # fmt: skip
        junk.put(b'{"id": 9, "pos_ned": ["nan", 0, 0]}')
        for k in range(3):
            pub.publish(k * 0.1, st)
        deadline = time.monotonic() + 5
        while sub.received < 9 and time.monotonic() < deadline:
            time.sleep(0.02)
        got = sub.states(3)
        assert got is not None and np.allclose(got.pos_ne, st.pos_ne)
        assert got.camouflaged.tolist() == [False, True, False]
        assert sub.latest[2]["t_sim"] == pytest.approx(0.2) and sub.corrupt == 1
        assert sub.states(4) is None  # UGV 3 never reported
    finally:
        b.close()
        a.close()

"""UGV states over Zenoh (`skyherd/ugv/<id>/state`) between two real sessions on loopback."""

import json
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


def test_a_state_payload_is_the_record_runio_mac_signs():
    """The signed body written directly is runio.mac's encoding of the record, whatever the
    numbers (NaN and ±inf, which JSON writes its own way, by the record); unsigned: as before."""
    import math
    import random

    from skyherd.groundsim.transport import state_payload
    from skyherd.runio.mac import payload_ok, sign_record

    key = bytes(range(32))
    awkward = [0.0, -0.0, 5e-324, 1e-300, 1e16, 1e22, 0.1 + 0.2, -2.5, 3, np.float64(7.25),
               math.nan, math.inf, -math.inf]  # fmt: skip
    rng = random.Random(5)
    for k in range(3000):
        nums = [rng.choice(awkward) if rng.random() < 0.3 else rng.uniform(-1e3, 1e3)
                for _ in range(5)]  # fmt: skip
        t, n, e, heading, speed = nums
        ugv, seq, camouflaged = k % 4, rng.randrange(10**6), rng.random() < 0.5
        rec = {"id": ugv, "seq": seq, "t_sim": float(t), "pos_ned": [float(n), float(e), 0.0],
               "heading_rad": float(heading), "speed_mps": float(speed),
               "camouflaged": camouflaged}  # fmt: skip
        for signing in (key, None):
            got = state_payload(signing, ugv, seq, t, n, e, heading, speed, np.bool_(camouflaged))
            assert got == sign_record(rec, signing), (nums, signing)
        if all(map(math.isfinite, nums)):  # a signed body written directly verifies
            payload = state_payload(key, ugv, seq, *nums, camouflaged)
            assert payload_ok(payload, json.loads(payload), key)

"""The state keys a split run's windows keep to find where two runs meet (runner.StateKeys)."""

from __future__ import annotations

import math
import pickle

from frontdiag.runner import StateKeys


def _key(kf: int, dts: list[float]) -> tuple:
    return ((kf, kf - 5, -1), 1_700_000_000_000_000_000 + kf, tuple(dts))


def test_equal_keys_match_and_keys_that_differ_in_any_value_do_not() -> None:
    k = StateKeys()
    k.add(10, _key(10, [0.1, 0.1, 0.1]))
    assert k.matches(10, _key(10, [0.1, 0.1, 0.1]))
    assert not k.matches(10, _key(10, [0.1, 0.1, math.nextafter(0.1, 1.0)]))  # the next float
    assert not k.matches(10, _key(11, [0.1, 0.1, 0.1]))
    assert not k.matches(10, None)
    assert not k.matches(11, _key(10, [0.1, 0.1, 0.1]))  # no key kept after frame 11
    assert k.get(11) is None
    assert StateKeys.digest(_key(3, [0.3])) != StateKeys.digest(_key(3, [0.1 + 0.2]))


def test_the_last_key_added_for_a_frame_wins_and_items_keep_the_order() -> None:
    a = StateKeys()
    a.add(1, "x")
    a.add(2, "y")
    assert a.get(2) == StateKeys.digest("y")
    b = StateKeys()
    b.add(2, "z")
    b.add(3, "w")
    a.update(b)  # a continued run's keys over the first run's
    assert [f for f, _ in a.items()] == [1, 2, 2, 3]
    assert a.matches(2, "z") and not a.matches(2, "y")
    assert len(a) == 4 and len(b) == 2


def test_state_keys_cross_to_another_process_whole() -> None:
    k = StateKeys()
    for f in range(50):
        k.add(f, _key(f, [0.05] * 20))
    assert k.matches(7, _key(7, [0.05] * 20))  # the index built before pickling is not sent
    back = pickle.loads(pickle.dumps(k))
    assert back.matches(49, _key(49, [0.05] * 20)) and not back.matches(50, _key(50, []))
    assert list(back.items()) == list(k.items())

"""ORION's memory carried across goals: regions keyed by place, corrective paints help a later goal."""

import numpy as np

from orion_eval.memory import MemoryMaps


def _memory():
    return MemoryMaps(lambda texts: np.ones((len(texts), 4)) / 2.0, threshold=0.95)


def test_region_keys_are_places():
    m = _memory()
    a = m.region_key((1.0, 1.0))
    assert m.region_key((1.3, 1.2)) == a  # within merge_m: the same place
    assert m.region_key((3.0, 1.0)) != a


def test_corrective_paint_helps_a_later_goal_but_yesno_does_not():
    cells = np.array([10, 11, 12])
    # goal 1 ("Alice's computer"): the agent found Bob's computer
    corrective, yesno = _memory(), _memory()
    for mem, pos in ((corrective, "Bob's computer"), (yesno, None)):
        mem.update(mem.region_key((2.0, 2.0)), cells, pos, "Alice's computer")
    # goal 2 ("Bob's computer") in the same scene, same run: only the corrective memory knows where it is
    pos, neg = corrective.retrieve("Bob's computer")
    assert pos == [1] and neg == []
    assert yesno.retrieve("Bob's computer") == ([], [])
    # the rejected place stays negative for goal 1's name in both
    assert corrective.retrieve("Alice's computer")[1] == [1] and yesno.retrieve("Alice's computer")[1] == [1]

"""Jobs in spawned processes (rmi_learn.process_pool): results in the jobs' order, the same
as in this process; a job's error reaches the caller."""

from __future__ import annotations

import math

import pytest

from rmi_learn.process_pool import ordered_map


def test_a_pool_gives_the_results_in_the_jobs_order() -> None:
    jobs = [9.0, 4.0, 1.0, 16.0, 25.0]
    assert list(ordered_map(math.sqrt, jobs, 2)) == list(ordered_map(math.sqrt, jobs, 1))
    assert list(ordered_map(math.sqrt, jobs, 2)) == [3.0, 2.0, 1.0, 4.0, 5.0]


def test_a_jobs_error_reaches_the_caller() -> None:
    with pytest.raises(ValueError, match="math domain error"):
        list(ordered_map(math.sqrt, [4.0, -1.0, 9.0], 2))

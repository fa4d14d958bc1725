"""A registered name becomes a job folder: one that could leave the sweep (or hide) is refused at registration."""

from __future__ import annotations

import pytest

from optimizers.registry import Registry


@pytest.mark.parametrize("name, why", [
    ("../escape", r"holds a '/' and '\.\.' and a leading '\.'"),
    ("a/b", "holds a '/'"),
    ("..", r"holds '\.\.' and a leading '\.'"),
    ("x..y", r"holds '\.\.'"),
    (".hidden", r"holds a leading '\.'"),
    ("back\\slash", r"holds a '\\'"),
    ("nul\0byte", "holds a NUL byte"),
    ("", "must be a non-empty string"),
    (None, "must be a non-empty string"),
])
def test_a_name_that_is_not_one_plain_folder_name_is_refused_at_registration(name, why):
    registry = Registry("optimizer", "optimizers")
    with pytest.raises(ValueError, match=why):
        @registry.register(name)
        class Plugin:
            pass
    assert registry._classes == {}


def test_plain_names_still_register():
    registry = Registry("problem", "bench.problems")

    @registry.register("my-opt_2.v1")
    class Plugin:
        pass

    assert registry._classes == {"my-opt_2.v1": Plugin} and Plugin.registered_name == "my-opt_2.v1"

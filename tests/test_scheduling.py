"""The longest-file-first order of tests/scheduling.py."""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from tests.scheduling import longest_first, recorded

FILES = st.sampled_from([f"tests/t{i}.py" for i in range(6)])


@given(
    st.lists(FILES, max_size=40),
    st.dictionaries(FILES, st.floats(min_value=0.1, max_value=500), max_size=4),
)
def test_longest_files_first_each_file_whole_and_in_order(
    files: list[str], seconds: dict[str, float]
) -> None:
    # Tests of one file arrive together, as pytest collects them.
    grouped = sorted(files, key=files.index)
    nodeids = [f"{name}::test_{i}" for i, name in enumerate(grouped)]
    order = longest_first(nodeids, seconds)
    assert sorted(order) == list(range(len(nodeids)))
    ran = [nodeids[i] for i in order]
    names = [n.split("::")[0] for n in ran]
    runs = [name for i, name in enumerate(names) if i == 0 or names[i - 1] != name]
    assert len(runs) == len(set(runs))  # each file in one piece
    for name in set(names):  # in its collected order
        mine = [n for n in ran if n.startswith(name + "::")]
        assert mine == [n for n in nodeids if n.startswith(name + "::")]
    weights = [seconds.get(name, 0.0) for name in runs]
    assert weights == sorted(weights, reverse=True)
    unknown = [name for name in runs if name not in seconds]
    assert unknown == [n for n in dict.fromkeys(names_in(nodeids)) if n not in seconds]


def names_in(nodeids: list[str]) -> list[str]:
    return [n.split("::")[0] for n in nodeids]


def test_a_missing_or_broken_record_changes_nothing(tmp_path: Path) -> None:
    assert recorded(tmp_path / "none.json") == {}
    broken = tmp_path / "broken.json"
    broken.write_text("{not json", encoding="utf-8")
    assert recorded(broken) == {}
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"tests/a.py": 3, "tests/b.py": "x"}), encoding="utf-8")
    assert recorded(good) == {"tests/a.py": 3.0}


def test_the_committed_record_names_files_that_exist() -> None:
    root = Path(__file__).resolve().parent.parent
    record = recorded()
    assert record, "tests/durations.json is missing or empty"
    missing = [name for name in record if not (root / name).is_file()]
    assert not missing, f"tests/durations.json names files that are gone: {missing}"

"""Every JSON document a user gives is read by one reader (`text_input.read_user_json`): whatever is wrong with
it (not JSON, the wrong kind of document, too large, not UTF-8, empty, nested without end), each format's reader
refuses it in one line that names the file and the problem, a syntax error with its line and column."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import pytest

from sosmatch.database.changes_io import read_changes_record
from sosmatch.database.match_io import read_match_json
from sosmatch.database.opensfm import read_opensfm_reconstruction
from sosmatch.database.session_io import read_map_record
from sosmatch.database.synth_session import ground_truth_frame, load_synth_session
from sosmatch.database.text_input import TEXT_LIMIT_BYTES
from sosmatch.plugin.errors import InputError
from sosmatch.workflows.merge_pairs import flight_maps
from sosmatch.workflows.poses import load_result

# format -> (the file's name in its folder, the reader called on the folder or the file)
READERS: dict[str, tuple[str, Callable[[Path], object]]] = {
    "match.json": ("match.json", lambda f: read_match_json(f)),
    "changes.json": ("changes.json", lambda f: read_changes_record(f)),
    "run.json": ("run.json", lambda f: read_map_record(f.parent)),
    "synth session.json": ("session.json", lambda f: load_synth_session(f.parent)),
    "synth ground truth": ("session.json", lambda f: ground_truth_frame(f.parent)),
    "OpenSfM reconstruction": ("reconstruction.json", lambda f: read_opensfm_reconstruction(f)),
    "poses.json": ("poses.json", lambda f: load_result(f.parent)),
    "merge.json": ("merge.json", lambda f: flight_maps(SimpleNamespace(path=f.parent))),  # type: ignore[arg-type]
}

# case -> (the file's bytes, or None for a sparse file over the read cap; what the error says)
CASES: dict[str, tuple[bytes | None, str]] = {
    "malformed": (b'{"format": "x",\n  "maps": [1, 2,,]}\n', r":2: cannot read .* not valid JSON.*column 17"),
    "wrong top-level type": (b'"just a string"\n', r"must hold a JSON (object|array).*, not a string"),
    "huge": (None, r"is larger than 256 MiB"),
    "not UTF-8": (b'{"format": "caf\xe9"}', r"not UTF-8 text \(byte 15\)"),
    "empty": (b"  \n", r"is empty \(an interrupted copy\?\)"),
    "nested without end": (b"[" * 200_000, r"nested too deeply"),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("fmt", list(READERS))
def test_a_bad_json_file_is_refused_in_one_line_naming_it(tmp_path: Path, fmt: str, case: str) -> None:
    name, read = READERS[fmt]
    content, says = CASES[case]
    path = tmp_path / name
    if content is None:
        with open(path, "wb") as f:  # sparse: its stat size is over the cap, nothing is read
            f.truncate(TEXT_LIMIT_BYTES + 1)
    else:
        path.write_bytes(content)
    with pytest.raises(InputError) as refused:
        read(path)
    message = str(refused.value)
    assert len(message.splitlines()) == 1 and message.startswith(str(path) + ":"), message
    assert refused.value.path == path
    assert re.search(says, message), message


def test_a_syntax_error_is_located_by_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "match.json"
    path.write_text('{\n "format": "sosmatch match v3",\n "hypotheses": [\n  {"score": 1.5,}\n ]\n}\n')
    with pytest.raises(InputError) as refused:
        read_match_json(path)
    assert refused.value.line == 4
    assert str(refused.value) == (f"{path}:4: cannot read match file: not valid JSON, truncated or another kind of "
                                  "file (Expecting property name enclosed in double quotes, column 17); re-run "
                                  "`sosmatch match`")


def test_a_merged_sessions_record_names_its_flights(tmp_path: Path) -> None:
    import pycolmap

    (tmp_path / "merge.json").write_text('{"format": "sosmatch merge v1", "flight_maps": ["b", "a", "b"]}\n')
    (tmp_path / "sparse").mkdir()
    pycolmap.Reconstruction().write(str(tmp_path / "sparse"))  # a merged session's model (its images' names)
    session = SimpleNamespace(path=tmp_path, sparse_dir=tmp_path / "sparse")
    assert flight_maps(session) == ["a", "b"]  # type: ignore[arg-type]

"""What the experiment commands share (pipeline.experiments.options): the overrides that make a setting and a
folder's command.txt."""

from pipeline.experiments.options import add_command, setting_overrides


def test_paths_overrides_are_no_setting_and_the_rest_keep_their_order():
    overrides = ["budget=cpu", "paths.results=r", "+paths.extra=x", "~paths.assets", "nvf.entropy.logdet_coeff=1.0"]
    assert setting_overrides(overrides) == ["budget=cpu", "nvf.entropy.logdet_coeff=1.0"]


def test_a_command_is_added_once_in_first_run_order(tmp_path):
    add_command(tmp_path, ["python", "-m", "x", "--scenes", "hotdog"])
    add_command(tmp_path, ["python", "-m", "x", "--label", "a b"])
    add_command(tmp_path, ["python", "-m", "x", "--scenes", "hotdog"])  # a rerun is not a new line
    lines = (tmp_path / "command.txt").read_text().splitlines()
    assert lines == ["python -m x --scenes hotdog", "python -m x --label 'a b'"]

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


def test_command_lines_name_folders_outside_the_repository_as_dir(tmp_path):
    """A committed ``command.txt`` named the folders of the machine a study ran on (``paths.results=/work/...``);
    now an absolute path outside the repository is kept as ``DIR``, paths inside it and other words as given."""
    from pipeline.repo import RUNS

    add_command(
        tmp_path,
        [
            "python",
            "-m",
            "x",
            f"paths.results={tmp_path}",
            "--records",
            "/elsewhere/runs",
            "--records",
            str(RUNS),
            "seed=3",
        ],
    )
    assert (
        tmp_path / "command.txt"
    ).read_text() == f"python -m x paths.results=DIR --records DIR --records {RUNS} seed=3\n"

"""An episode's progress: a status line on a terminal from the first training iteration (stage, step, time
left), no bar elsewhere but one line per finished step."""

from pipeline.episode.progress import EpisodeProgress, clock


def test_clock_reads_minutes_and_hours():
    assert clock(5.0) == "0:05" and clock(125.4) == "2:05" and clock(3723.0) == "1:02:03"


def test_on_a_terminal_the_line_shows_stage_step_and_time_left(capsys):
    with EpisodeProgress("default/nvf cpu seed 0", 0, 3, ["backbone", "variance"], interactive=True) as progress:
        progress.train("backbone", 0, 10, 0.5)
        progress.bar.refresh()
        first = capsys.readouterr().err
        for i in range(10):
            progress.train("backbone", i, 10, 0.5)
        for i in range(4):
            progress.train("variance", i, 4, 0.1)
        after_training = capsys.readouterr().err
        progress.step_done(0, 4, 14.25, 2.0)
        progress.train("backbone", 0, 10, 0.4)
        progress.bar.refresh()
        later = capsys.readouterr()
    assert "default/nvf cpu seed 0 step 0/3" in first and "training backbone 1/10" in first
    assert "episode ETA ?" in first  # unknown until a step has finished
    assert "evaluating and planning" in after_training
    assert "step 1/3" in later.err and "episode ETA ?" not in later.err
    assert "step 0: 4 views, PSNR 14.25 dB" in later.err
    assert later.out == ""


def test_off_a_terminal_no_bar_one_line_per_step(capsys):
    with EpisodeProgress("default/random smoke seed 1", 1, 3, ["backbone"], interactive=False) as progress:
        progress.train("backbone", 0, 10, 0.5)
        progress.step_done(1, 5, 12.5, 1.25)
    captured = capsys.readouterr()
    assert captured.err == ""
    assert captured.out == "[default/random smoke seed 1] step 1: 5 views, PSNR 12.50 dB, 1.2 s\n"

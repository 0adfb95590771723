"""`jaxba batch`'s progress bar: only the plain lines off a terminal, a bar when asked."""

from jaxba._cli._progress_bar import project_progress


def _report(bar):
    lines = []
    with project_progress(3, lines.append, bar=bar) as progress:
        progress.say("read 3 projects")
        for _ in range(3):
            progress.advance()
    return lines


def test_no_bar_off_a_terminal(capsys):
    # pytest captures stdout: not a terminal, so the default (None) is off.
    assert _report(None) == ["read 3 projects"]
    assert capsys.readouterr().out == ""
    assert _report(False) == ["read 3 projects"]


def test_bar_when_asked_counts_projects_below_the_lines(capsys):
    assert _report(True) == []  # the lines go to the bar's console instead
    out = capsys.readouterr().out
    assert "read 3 projects" in out
    assert "3/3" in out and "projects" in out
    assert out.index("read 3 projects") < out.rindex("3/3")

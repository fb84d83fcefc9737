"""``relcal board`` writes a printable sheet and the YAML a dataset can name."""

from relcal.cli import main
from relcal.vision.boards import load_board


def test_board_command_writes_pdf_and_yaml(tmp_path, capsys):
    argv = ["board", "--type", "charuco", "--rows", "7", "--columns", "5", "--square", "0.036195"]
    argv += ["--marker", "0.018256", "--dictionary", "DICT_6X6_250"]
    argv += ["--out", str(tmp_path / "b.pdf"), "--yaml", str(tmp_path / "b.yaml")]
    assert main(argv) == 0
    assert (tmp_path / "b.pdf").read_bytes()[:4] == b"%PDF"
    board = load_board(tmp_path / "b.yaml")
    assert (board.type, board.rows, board.columns, board.spacing) == ("charuco", 7, 5, 0.036195)
    assert "written to" in capsys.readouterr().out

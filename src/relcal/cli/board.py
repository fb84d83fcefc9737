"""``relcal board``: a printable board at true scale with its geometry printed on it."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import (
    existing_file,
    json_arg,
    length_m,
    output_file,
    positive_float,
    positive_int,
)

EPILOG = """\
examples:
  relcal board --type chessboard --rows 7 --columns 10 --square 0.02 --out board.pdf --json b.json
  relcal board --type charuco --rows 7 --columns 5 --square 0.036195 --marker 0.018256 \\
               --dictionary DICT_6X6_250 --out charuco.png --dpi 600
  relcal board --spec board.yaml --out board.pdf      # the same YAML a dataset names

Print at 100 % (no "fit to page") and check the 50 mm bar with a ruler.
"""


def run(args: argparse.Namespace) -> int:
    from relcal.errors import RelcalError
    from relcal.io import File, json_text, validate, write_set, yaml_text
    from relcal.outputset import check
    from relcal.vision.boards import BoardSpec, board_to_spec, load_board, printable

    named = ((args.out, "--out"), (args.yaml, "--yaml"), (args.json, "--json"))
    if args.spec:
        board = load_board(args.spec)
    else:
        if not args.type:
            raise RelcalError("relcal board: give --spec FILE or --type with its sizes")
        fields = {
            "type": args.type,
            "rows": args.rows,
            "columns": args.columns,
            "square" if args.type in ("chessboard", "charuco") else "spacing": args.square,
            "marker": args.marker,
            "dictionary": args.dictionary,
        }
        board = validate(BoardSpec, {k: v for k, v in fields.items() if v is not None}, "options")
        board = board.to_board()
    check([File(p, b"", what) for p, what in named if p])
    path = Path(args.out)
    items = [File(path, printable(board, path, dpi=args.dpi), "--out")]
    if args.yaml:
        items.append(File(args.yaml, yaml_text(board_to_spec(board)), "--yaml"))
    if args.json:
        from relcal.reporting.documents import board_document

        doc = board_document(board, path, args.dpi)
        items.append(File(args.json, json_text({**doc, "yaml": args.yaml}), "--json"))
    write_set(*items)
    if not args.quiet:
        print(f"{board.describe()}\nwritten to {path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "board",
        help="write a printable calibration board (PDF or PNG) at true scale",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--spec", type=existing_file, help="board YAML (relcal or robot_cal_tools target.yaml)"
    )
    p.add_argument("--type", choices=("chessboard", "charuco", "circles", "acircles"))
    p.add_argument(
        "--rows", type=positive_int, help="squares (chessboard, charuco) or dots (grids)"
    )
    p.add_argument("--columns", type=positive_int)
    p.add_argument(
        "--square", type=length_m(0, 0.5), help="square size or dot spacing, m (at most 0.5)"
    )
    p.add_argument(
        "--marker", type=length_m(0, 0.5), help="ArUco marker size (charuco), m (at most 0.5)"
    )
    p.add_argument("--dictionary", help="ArUco dictionary, e.g. DICT_6X6_250")
    p.add_argument("--out", required=True, type=output_file, help="output .pdf or .png")
    p.add_argument("--dpi", type=positive_float, default=300.0, help="PNG resolution (default 300)")
    p.add_argument(
        "--yaml",
        type=output_file,
        help="also write the board description as YAML for dataset.yaml",
    )
    json_arg(p, "the board geometry (m), the file written and its page size (mm)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)

"""``relcal board``: a printable board at true scale with its geometry printed on it."""

from __future__ import annotations

import argparse

from relcal.cli.common import json_arg

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
    from relcal.io import validate, write_text
    from relcal.vision.boards import BoardSpec, board_to_spec, load_board, write_printable

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
    path = write_printable(board, args.out, dpi=args.dpi)
    if args.yaml:
        import yaml

        write_text(args.yaml, yaml.safe_dump(board_to_spec(board), sort_keys=False))
    if args.json:
        from relcal.io import write_json
        from relcal.reporting.documents import board_document

        doc = board_document(board, path, args.dpi)
        write_json(args.json, {**doc, "yaml": args.yaml})
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
    p.add_argument("--spec", help="board YAML (relcal or robot_cal_tools target.yaml)")
    p.add_argument("--type", choices=("chessboard", "charuco", "circles", "acircles"))
    p.add_argument("--rows", type=int, help="squares (chessboard, charuco) or dots (grids)")
    p.add_argument("--columns", type=int)
    p.add_argument("--square", type=float, help="square size or dot spacing, m")
    p.add_argument("--marker", type=float, help="ArUco marker size (charuco), m")
    p.add_argument("--dictionary", help="ArUco dictionary, e.g. DICT_6X6_250")
    p.add_argument("--out", required=True, help="output .pdf or .png")
    p.add_argument("--dpi", type=float, default=300.0, help="PNG resolution (default 300)")
    p.add_argument("--yaml", help="also write the board description as YAML for dataset.yaml")
    json_arg(p, "the board geometry (m), the file written and its page size (mm)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)

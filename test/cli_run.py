"""The CLI run in-process, as the tests of its commands call it."""
from zeroshot_calib_ros.cli import main


def run_main(args, capsys):
    """(exit status, stdout, stderr lines) of main(args) in-process; argparse exits included."""
    try:
        status = main(args)
    except SystemExit as exc:
        status = exc.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err.strip().splitlines()

"""Write an editable copy of the shipped configuration into a folder.

    automotive config export DIR [--overwrite]     properties/, qos/ and idl/ of the installed package into DIR
    automotive config path                         where the shipped configuration is (read-only)

The copy keeps the layout, so its relative paths (``qos.File=../qos/automotive_qos.xml``, ``dataFile=data/...``)
point at its own files: ``automotive-vision --properties DIR/properties/vision.properties`` then runs on the copy,
and the recorder, the replayer and the bridge started with a properties file of DIR/properties read the writing
applications' files there too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from automotive import config
from automotive.bus.cli import EXIT_BAD_INPUT, ArgumentParser

PROG = "automotive config"


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True, metavar="{export,path}")
    export = commands.add_parser("export", help="copy the shipped configuration into DIR")
    export.add_argument("folder", type=Path, metavar="DIR", help="the folder to write (created if needed)")
    export.add_argument("--overwrite", action="store_true", help="replace files that exist")
    commands.add_parser("path", help="print where the shipped configuration is")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "path":
        print(config.shipped_dir())
        return 0
    folder: Path = args.folder
    if folder.exists() and not folder.is_dir():
        print(f"{PROG}: {folder} is not a folder", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        written = config.export(folder, args.overwrite)
    except FileExistsError as error:
        print(f"{PROG}: {error} exists (add --overwrite to replace the files)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:
        print(f"{PROG}: cannot write into {folder} ({error.strerror})", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"wrote {len(written)} files into {folder}: properties/ (one per program, data/ with the CSV files), qos/, "
          f"idl/; run a program on them with --properties {folder / 'properties' / '<program>.properties'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

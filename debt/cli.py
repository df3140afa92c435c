"""`rovlink debt encode|decode`: the DEBT image codec on files.

    rovlink debt encode IN.png OUT.debt --bytes 2000 [--roi x0,y0,x1,y1] [--shift 6] [--mono]
    rovlink debt decode IN.debt OUT.png [--prefix N]

Images are read and written with Pillow (any format it knows); grey images
stay grey, anything else is coded as RGB unless --mono.
"""

from __future__ import annotations

import argparse

from rovlink.command import CommandError, positive_int


def _roi(text: str) -> tuple[int, int, int, int]:
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or min(values) < 0:
        raise argparse.ArgumentTypeError(f"must be x0,y0,x1,y1 (four non-negative integers), got {text!r}")
    return values  # type: ignore[return-value]


def _shift(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 15:
        raise argparse.ArgumentTypeError(f"must be an integer 0..15, got {text!r}")
    return value


def _prefix(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative number of bytes, got {text!r}")
    return value


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "debt",
        help="encode or decode images with the DEBT progressive codec",
        description=(
            "DEBT (Depth Embedded Block Tree): wavelet, embedded block-tree bit-plane coder "
            "with a region of interest, arithmetic coder. Every prefix of a stream is a picture."
        ),
    )
    inner = parser.add_subparsers(dest="debt_command", metavar="ACTION", parser_class=type(parser))
    inner.required = True

    enc = inner.add_parser(
        "encode",
        help="code an image into a DEBT stream of at most --bytes bytes",
        description="Code an image file into a DEBT stream of at most --bytes bytes.",
        epilog="example: rovlink debt encode assets/images/seabed.png seabed.debt --bytes 2000 "
        "--roi 107,80,213,160 --shift 6",
    )
    enc.add_argument("input", metavar="IN", help="image file (PNG, JPEG, ...)")
    enc.add_argument("output", metavar="OUT", help="DEBT stream to write")
    enc.add_argument("--bytes", dest="budget", type=positive_int, required=True, metavar="N",
                     help="byte budget of the stream (the header included)")
    enc.add_argument("--roi", type=_roi, metavar="X0,Y0,X1,Y1",
                     help="region of interest in pixels, (X1, Y1) exclusive")
    enc.add_argument("--shift", type=_shift, default=6, metavar="S",
                     help="bit planes the ROI is raised, 0..15 (default 6; used only with --roi)")
    enc.add_argument("--mono", action="store_true", help="code luminance only")
    enc.set_defaults(func=run_encode)

    dec = inner.add_parser(
        "decode",
        help="decode a DEBT stream (or its first N bytes) into an image",
        description="Decode a DEBT stream, or only its first --prefix bytes, into an image file.",
        epilog="example: rovlink debt decode seabed.debt seabed.png --prefix 600",
    )
    dec.add_argument("input", metavar="IN", help="DEBT stream")
    dec.add_argument("output", metavar="OUT", help="image file to write (format from its extension)")
    dec.add_argument("--prefix", type=_prefix, metavar="N", help="decode only the first N bytes")
    dec.set_defaults(func=run_decode)


def run_encode(args) -> int:
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    from rovlink import debt

    try:
        with Image.open(args.input) as im:
            grey = im.mode in ("L", "1", "I", "I;16", "F")
            image = np.asarray(im.convert("L" if grey else "RGB"))
    except FileNotFoundError:
        raise CommandError(f"no such file: {args.input}") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise CommandError(f"cannot read image {args.input}: {exc}") from None
    try:
        data = debt.encode(image, args.budget, roi=args.roi, shift=args.shift if args.roi else 0,
                           mono=True if args.mono else None)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    try:
        with open(args.output, "wb") as f:
            f.write(data)
    except OSError as exc:
        raise CommandError(f"cannot write {args.output}: {exc.strerror}") from None
    h, w = image.shape[:2]
    kind = "grey" if image.ndim == 2 or args.mono else "colour"
    print(f"{args.input}: {w}x{h} {kind} -> {args.output}: {len(data)} bytes")
    return 0


def run_decode(args) -> int:
    from PIL import Image

    from rovlink import debt

    try:
        with open(args.input, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise CommandError(f"no such file: {args.input}") from None
    except OSError as exc:
        raise CommandError(f"cannot read {args.input}: {exc.strerror}") from None
    if args.prefix is not None:
        data = data[:args.prefix]
    try:
        image = debt.decode(data)
    except ValueError as exc:
        raise CommandError(f"{args.input}: {exc}") from None
    try:
        Image.fromarray(image).save(args.output)
    except (ValueError, OSError) as exc:
        raise CommandError(f"cannot write {args.output}: {exc}") from None
    h, w = image.shape[:2]
    print(f"{args.input}: {len(data)} bytes -> {args.output}: {w}x{h}")
    return 0

"""`rovlink bench debt`: DEBT beside JPEG 2000, WebP, AVIF and JPEG.

On three 320x240 images the project ships (assets/images: a synthetic grey
outdoor scene, a colour still life and an underwater seabed; see
assets/images/README.md) and budgets of 500, 1000, 2000 and 4000 bytes:

- PSNR and SSIM of DEBT beside OpenJPEG's JPEG 2000 (through Pillow:
  irreversible 9/7, mct for colour, one quality layer, raw codestream), WebP
  (method 6), AVIF and baseline JPEG, each at the largest setting whose output
  fits the budget;
- ROI PSNR over the centre ninth of the image at SHIFT 4 and 6, beside JPEG
  2000's PSNR over the same rectangle at the same budget;
- the progressive curve: PSNR of every 64-byte prefix of a 4000-byte stream,
  beside the 4000-byte JPEG 2000 codestream cut at the same bytes;
- encode and decode milliseconds (median of several runs) beside OpenJPEG's,
  in the same run.

PSNR is over all samples (RGB for colour); SSIM is the Gaussian-window
(sigma 1.5) index of Wang et al., averaged over channels.
"""

from __future__ import annotations

import io
import statistics
import time

from rovlink.assets import ASSETS_DIR

from .table import emit, format_table

BUDGETS = (500, 1000, 2000, 4000)
IMAGES = ("grey-scene", "colour-still-life", "seabed")
CURVE_BYTES = 4000
CURVE_STEP = 64
TIMING_BUDGET = 2000


# ---------------------------------------------------------------- metrics

def psnr(a, b) -> float:
    import numpy as np

    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else float(10.0 * np.log10(255.0 ** 2 / mse))


def _gauss_filter(x, taps):
    # Separable 'valid' filtering by shifted sums: no scipy needed.
    n = len(taps)
    h, w = x.shape
    rows = sum(t * x[i:h - n + 1 + i] for i, t in enumerate(taps))
    return sum(t * rows[:, i:w - n + 1 + i] for i, t in enumerate(taps))


def ssim(a, b) -> float:
    import numpy as np

    a = a.astype(np.float64)
    b = b.astype(np.float64)
    if a.ndim == 3:
        return float(np.mean([ssim(a[..., c], b[..., c]) for c in range(a.shape[2])]))
    r = np.arange(-5, 6)
    taps = np.exp(-(r ** 2) / (2 * 1.5 ** 2))
    taps /= taps.sum()
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    mu_a, mu_b = _gauss_filter(a, taps), _gauss_filter(b, taps)
    saa = _gauss_filter(a * a, taps) - mu_a ** 2
    sbb = _gauss_filter(b * b, taps) - mu_b ** 2
    sab = _gauss_filter(a * b, taps) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * sab + c2)
    den = (mu_a ** 2 + mu_b ** 2 + c1) * (saa + sbb + c2)
    return float(np.mean(num / den))


# ---------------------------------------------------------------- reference codecs

def _pil_decode(data: bytes, like):
    import numpy as np
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        out = np.asarray(im.convert("L" if like.ndim == 2 else "RGB"))
    return out


def j2k_encode(img, ratio: float) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img).save(buf, "JPEG2000", quality_mode="rates", quality_layers=[ratio],
                              irreversible=True, no_jp2=True, mct=1 if img.ndim == 3 else 0)
    return buf.getvalue()


def j2k_fit(img, budget: int) -> tuple[bytes, float]:
    """The largest one-layer codestream within `budget` (bisection on the rate)."""
    raw = img.size
    lo, hi = raw / budget * 0.5, raw / budget * 4.0
    best: tuple[bytes, float] | None = None
    for _ in range(22):
        ratio = (lo * hi) ** 0.5
        data = j2k_encode(img, ratio)
        if len(data) <= budget:
            if best is None or len(data) > len(best[0]):
                best = (data, ratio)
            hi = ratio
        else:
            lo = ratio
        if hi / lo < 1.002:
            break
    if best is None:
        best = (j2k_encode(img, hi), hi)
    return best


def _quality_fit(encode, budget: int, low: int, high: int) -> tuple[bytes | None, int | None]:
    # Largest integer quality whose output fits (sizes grow with quality).
    best = (None, None)
    while low <= high:
        q = (low + high) // 2
        data = encode(q)
        if len(data) <= budget:
            best = (data, q)
            low = q + 1
        else:
            high = q - 1
    return best


def _pil_encoder(img, fmt: str, **options):
    from PIL import Image

    pil = Image.fromarray(img)
    if fmt in ("WEBP", "AVIF") and img.ndim == 2:
        pil = pil.convert("RGB")

    def encode(q: int) -> bytes:
        buf = io.BytesIO()
        pil.save(buf, fmt, quality=q, **options)
        return buf.getvalue()

    return encode


def reference_codecs(img, budget: int) -> dict[str, dict]:
    out = {}
    data, ratio = j2k_fit(img, budget)
    dec = _pil_decode(data, img)
    out["jpeg2000"] = dict(bytes=len(data), psnr=psnr(img, dec), ssim=ssim(img, dec), setting=round(ratio, 3))
    for name, fmt, options, lo in [("webp", "WEBP", dict(method=6), 0),
                                   ("avif", "AVIF", dict(), 0),
                                   ("jpeg", "JPEG", dict(optimize=True), 1)]:
        try:
            data, q = _quality_fit(_pil_encoder(img, fmt, **options), budget, lo, 100 if fmt != "JPEG" else 95)
        except (OSError, KeyError, ValueError):
            data, q = None, None
        if data is None:
            out[name] = dict(bytes=None, psnr=None, ssim=None, setting=None)
            continue
        dec = _pil_decode(data, img)
        out[name] = dict(bytes=len(data), psnr=psnr(img, dec), ssim=ssim(img, dec), setting=q)
    return out


def j2k_cut_psnr(img, stream: bytes, n: int) -> float | None:
    """PSNR of a JPEG 2000 codestream cut at n bytes, or None if undecodable."""
    from PIL import ImageFile

    old = ImageFile.LOAD_TRUNCATED_IMAGES
    ImageFile.LOAD_TRUNCATED_IMAGES = True
    try:
        return psnr(img, _pil_decode(stream[:n], img))
    except Exception:  # any failure of the reference decoder counts as "no picture"
        return None
    finally:
        ImageFile.LOAD_TRUNCATED_IMAGES = old


# ---------------------------------------------------------------- images

def load_images() -> dict:
    import numpy as np
    from PIL import Image

    from rovlink.debt import samples

    folder = ASSETS_DIR / "images"
    images = {}
    for name in IMAGES:
        path = folder / f"{name}.png"
        if path.exists():
            with Image.open(path) as im:
                images[name] = np.asarray(im.convert("L" if im.mode == "L" else "RGB"))
        else:  # installed without assets: draw them
            images[name] = samples.sample(name)
    return images


def _median_ms(fn, runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def centre_ninth(img) -> tuple[int, int, int, int]:
    h, w = img.shape[:2]
    return (w // 3, h // 3, w // 3 + w // 3, h // 3 + h // 3)


# ---------------------------------------------------------------- run

def measure(runs: int = 7, curve: bool = True) -> dict:
    from rovlink import debt

    images = load_images()
    debt.decode(debt.encode(images["grey-scene"][:16, :16], 100))  # JIT warm-up, not timed

    quality = []
    for name, img in images.items():
        for budget in BUDGETS:
            data = debt.encode(img, budget)
            dec = debt.decode(data)
            row = dict(image=name, budget=budget,
                       debt=dict(bytes=len(data), psnr=psnr(img, dec), ssim=ssim(img, dec)))
            row.update(reference_codecs(img, budget))
            quality.append(row)

    roi_rows = []
    for name, img in images.items():
        roi = centre_ninth(img)
        x0, y0, x1, y1 = roi
        inside = (slice(y0, y1), slice(x0, x1))
        for budget in (1000, 2000):
            j2k, _ = j2k_fit(img, budget)
            jdec = _pil_decode(j2k, img)
            plain = debt.decode(debt.encode(img, budget))
            row = dict(image=name, budget=budget, roi=list(roi),
                       jpeg2000_roi_psnr=psnr(img[inside], jdec[inside]),
                       debt_no_roi_psnr=psnr(img[inside], plain[inside]))
            for shift in (4, 6):
                dec = debt.decode(debt.encode(img, budget, roi=roi, shift=shift))
                row[f"shift{shift}_roi_psnr"] = psnr(img[inside], dec[inside])
                row[f"shift{shift}_psnr"] = psnr(img, dec)
            roi_rows.append(row)

    curves = {}
    if curve:
        for name, img in images.items():
            stream = debt.encode(img, CURVE_BYTES)
            j2k, _ = j2k_fit(img, CURVE_BYTES)
            points = []
            for n in range(CURVE_STEP, CURVE_BYTES + 1, CURVE_STEP):
                points.append(dict(bytes=n, debt=psnr(img, debt.decode(stream[:n])),
                                   jpeg2000_cut=j2k_cut_psnr(img, j2k, n)))
            values = [p["debt"] for p in points]
            curves[name] = dict(points=points,
                                monotone=all(b >= a for a, b in zip(values, values[1:])))

    timing = []
    for name, img in images.items():
        data = debt.encode(img, TIMING_BUDGET)
        j2k, ratio = j2k_fit(img, TIMING_BUDGET)
        timing.append(dict(
            image=name, budget=TIMING_BUDGET,
            debt_encode_ms=_median_ms(lambda: debt.encode(img, TIMING_BUDGET), runs),
            debt_decode_ms=_median_ms(lambda: debt.decode(data), runs),
            openjpeg_encode_ms=_median_ms(lambda: j2k_encode(img, ratio), runs),
            openjpeg_decode_ms=_median_ms(lambda: _pil_decode(j2k, img), runs),
        ))

    margins = [r["debt"]["psnr"] - r["jpeg2000"]["psnr"] for r in quality]
    ahead_webp = sum(r["webp"]["psnr"] is None or r["debt"]["psnr"] >= r["webp"]["psnr"] for r in quality)
    ahead_avif = sum(r["avif"]["psnr"] is None or r["debt"]["psnr"] >= r["avif"]["psnr"] for r in quality)
    roi_gain = [r["shift6_roi_psnr"] - r["jpeg2000_roi_psnr"] for r in roi_rows if r["budget"] == 1000]
    grey_t = timing[0]
    targets = dict(
        psnr_vs_jpeg2000_min_margin_db=min(margins),
        psnr_ge_jpeg2000_everywhere=bool(min(margins) >= 0),
        ahead_of_webp=f"{ahead_webp}/{len(quality)}",
        ahead_of_avif=f"{ahead_avif}/{len(quality)}",
        roi_shift6_1000B_gain_over_jpeg2000_min_db=min(roi_gain),
        roi_target_met=bool(min(roi_gain) >= 4.0),
        encode_ratio_vs_openjpeg=grey_t["debt_encode_ms"] / grey_t["openjpeg_encode_ms"],
        decode_ratio_vs_openjpeg=grey_t["debt_decode_ms"] / grey_t["openjpeg_decode_ms"],
        curves_monotone=all(c["monotone"] for c in curves.values()) if curves else None,
    )
    targets["speed_target_met"] = bool(targets["encode_ratio_vs_openjpeg"] <= 2.0
                                       and targets["decode_ratio_vs_openjpeg"] <= 2.0)
    return dict(quality=quality, roi=roi_rows, curves=curves, timing=timing, targets=targets)


def render(result: dict) -> str:
    parts = []
    codecs = ("debt", "jpeg2000", "webp", "avif", "jpeg")
    rows = []
    for r in result["quality"]:
        for c in codecs:
            v = r[c]
            rows.append([r["image"], r["budget"], c, v["bytes"],
                         None if v["psnr"] is None else round(v["psnr"], 2),
                         None if v["ssim"] is None else round(v["ssim"], 4)])
    parts.append("Whole-image quality, each codec at its largest setting within the budget")
    parts.append(format_table(["image", "budget", "codec", "bytes", "PSNR dB", "SSIM"], rows))

    rows = [[r["image"], r["budget"], ",".join(map(str, r["roi"])), round(r["jpeg2000_roi_psnr"], 2),
             round(r["debt_no_roi_psnr"], 2), round(r["shift4_roi_psnr"], 2), round(r["shift6_roi_psnr"], 2),
             round(r["shift6_roi_psnr"] - r["jpeg2000_roi_psnr"], 2), round(r["shift6_psnr"], 2)]
            for r in result["roi"]]
    parts.append("\nROI PSNR over the centre ninth (dB)")
    parts.append(format_table(["image", "budget", "roi", "j2k", "debt", "debt s4", "debt s6",
                               "s6 - j2k", "s6 whole"], rows))

    if result["curves"]:
        names = list(result["curves"])
        headers = ["prefix B"]
        for n in names:
            headers += [f"{n} debt", "j2k cut"]
        rows = []
        for i, p in enumerate(result["curves"][names[0]]["points"]):
            row = [p["bytes"]]
            for n in names:
                q = result["curves"][n]["points"][i]
                row += [round(q["debt"], 2), None if q["jpeg2000_cut"] is None else round(q["jpeg2000_cut"], 2)]
            rows.append(row)
        parts.append(f"\nProgressive curve: PSNR of {CURVE_STEP}-byte prefixes of a {CURVE_BYTES}-byte stream "
                     "(j2k: its codestream cut there; - = undecodable)")
        parts.append(format_table(headers, rows))

    rows = [[t["image"], t["budget"], round(t["debt_encode_ms"], 2), round(t["openjpeg_encode_ms"], 2),
             round(t["debt_decode_ms"], 2), round(t["openjpeg_decode_ms"], 2)] for t in result["timing"]]
    parts.append("\nMilliseconds, median of runs (same process)")
    parts.append(format_table(["image", "budget", "debt enc", "openjpeg enc", "debt dec", "openjpeg dec"], rows))

    t = result["targets"]
    parts.append("\nTargets")
    parts.append(format_table(["target", "value", "met"], [
        ["PSNR - JPEG 2000, worst case (dB)", round(t["psnr_vs_jpeg2000_min_margin_db"], 2),
         t["psnr_ge_jpeg2000_everywhere"]],
        ["ahead of WebP (cases)", t["ahead_of_webp"], None],
        ["ahead of AVIF (cases)", t["ahead_of_avif"], None],
        ["ROI s6 @1000 B - j2k ROI, worst (dB)", round(t["roi_shift6_1000B_gain_over_jpeg2000_min_db"], 2),
         t["roi_target_met"]],
        ["encode time / OpenJPEG (grey, 2000 B)", round(t["encode_ratio_vs_openjpeg"], 2),
         t["encode_ratio_vs_openjpeg"] <= 2.0],
        ["decode time / OpenJPEG (grey, 2000 B)", round(t["decode_ratio_vs_openjpeg"], 2),
         t["decode_ratio_vs_openjpeg"] <= 2.0],
        ["progressive curves monotone", t["curves_monotone"], t["curves_monotone"]],
    ]))
    return "\n".join(parts)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "debt",
        help="DEBT image codec beside JPEG 2000, WebP, AVIF and JPEG: quality, ROI, prefixes, speed",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--runs", type=int, default=7, metavar="N", help="timing runs per figure (default 7)")
    p.add_argument("--no-curve", action="store_true", help="skip the progressive curve")
    p.set_defaults(func=run)


def run(args) -> int:
    from PIL import features

    from rovlink.command import CommandError

    if not features.check("jpg_2000"):
        raise CommandError("this Pillow has no JPEG 2000 (OpenJPEG) support; the benchmark needs it")
    if args.runs < 1:
        raise CommandError("--runs must be at least 1")
    result = measure(runs=args.runs, curve=not args.no_curve)
    emit(result, render(result), args.json)
    return 0

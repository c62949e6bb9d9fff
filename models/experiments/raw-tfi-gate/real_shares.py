"""The real streams' reference frames with the gate before this stop's and the shipped one: reference, RMB-Net's
binned frame, raw TFI-16, both gated frames (each scaled onto the reference by least squares, linear PSNR in the
label) and the shipped gate's TFI-16 share (black 0, white 1), on a crop at twice the size. Reads the frames cached by
``frame_features.py cache`` (DIR). Run from the repository root:

    git show 6c1a9f5:models/raw-gate.safetensors > /tmp/old-gate.safetensors
    git show 6c1a9f5:models/raw-gate.json > /tmp/old-gate.json
    python models/experiments/raw-tfi-gate/real_shares.py DIR /tmp/old-gate.safetensors

writes ``models/figures/raw-gate-real.png``.
"""

import sys

import cv2
import numpy as np
import torch

import frame_features as ff
from rmbvideo.evaluate.real_video import least_squares_gain, scaled_psnr
from rmbvideo.net.raw_gate import gate_features
from rmbvideo.net.weights import load_raw_gate

T = ff._tensor


def main(folder: str, before: str) -> None:
    gates = {"gate before": load_raw_gate(before)[0].eval(),
             "this gate": load_raw_gate("models/raw-gate.safetensors")[0].eval()}
    rows = []
    for name in ("200_part3_key_id151", "203_part3_key_id151"):
        d = np.load(f"{folder}/real-{name}.npz")
        ref = d["reference"]
        ims = [ref, d["binned"], d["long"]]
        labels = ["reference", f"binned {scaled_psnr(d['binned'], ref):.2f}",
                  f"TFI-16 {scaled_psnr(d['long'], ref):.2f}"]
        images = [T(d[k]) for k in ("binned", "tfi", "previous", "long")]
        features = gate_features(*images[:3], float(d["convention"]), images[3], frame=True)
        for gname, g in gates.items():
            with torch.no_grad():
                shares = g.share(features)[0].numpy()  # TFI-4's and TFI-16's
            mixed = (1 - shares.sum(0)) * d["binned"] + shares[0] * d["tfi"] + shares[1] * d["long"]
            share = shares[1]
            ims.append(mixed)
            labels.append(f"{gname} {scaled_psnr(mixed, ref):.2f}")
        ims.append(share); labels.append("this gate: TFI-16 share")
        tiles = []
        for im, lab in zip(ims, labels):
            x = im if lab.startswith("this gate: TFI") or lab == "reference" else least_squares_gain(im, ref) * im
            t = (np.clip(x, 0, 1) * 255).astype(np.uint8)
            t = cv2.resize(t[20:100, 40:160], None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
            t = cv2.copyMakeBorder(t, 18, 2, 2, 2, cv2.BORDER_CONSTANT, value=255)
            cv2.putText(t, lab, (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 0, 1, cv2.LINE_AA)
            tiles.append(t)
        rows.append(np.concatenate(tiles, 1))
    cv2.imwrite("models/figures/raw-gate-real.png", np.concatenate(rows, 0))


if __name__ == "__main__":
    torch.set_num_threads(1)
    main(sys.argv[1], sys.argv[2])

"""Stage 18's average (tried, not shipped); run from the repository root after ``rmbvideo train video-temporal-gpu``
has written its weights to ``gpu-run.*`` here:

    python models/training/rmbnet-binned-stage18/make.py

Stage 17 and its GPU continuation with the temporal term (``video-temporal-gpu``: every weight, 365 steps of batch 8
in 5 minutes on an H100) averaged half and half (``avg`` here), as stage 17 was made from stage 16, because every GPU
continuation of every weight has read the dark end too dark alone. The head of ``avg`` was then trained with
``video-temporal-head-gpu`` (``loss.csv`` in ``head/``, its checkpoint in the history at 0488360). On the development sets the result
matched stage 17 (models/README, stage 18), so nothing was written as the default. The run's own weights and
checkpoint did not come back from the device (at most 8 files a call); ``avg`` did, and the run is 2 x avg - stage 17
to float rounding.
"""

from rmbvideo.net.weights import average_models, load_model, save_model

HERE = "models/training/rmbnet-binned-stage18"
STAGE17 = "models/training/rmbnet-binned/stage17.safetensors"


def main() -> None:
    stage17, _ = load_model(STAGE17)
    gpu_run, card = load_model(f"{HERE}/gpu-run.safetensors")
    save_model(f"{HERE}/avg.safetensors", average_models(stage17, gpu_run, 0.5), card)


if __name__ == "__main__":
    main()

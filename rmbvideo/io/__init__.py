"""Input and output: ``.dat`` spike streams in, frames (MP4, EXR, PNG) out."""

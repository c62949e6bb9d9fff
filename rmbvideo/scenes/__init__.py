"""HDR scenes that can be rendered exactly at any time, with ground-truth flow."""

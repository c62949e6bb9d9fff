"""Streaming reconstruction: preliminary frames, classical methods, RMB-Net engine, tone mapping."""

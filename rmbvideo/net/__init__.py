"""RMB-Net (paper Sec. 4.2): one small module per part, composed in ``model.py``."""

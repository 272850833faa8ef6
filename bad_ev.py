import numpy as np
class B:
    def __init__(self, c, n, s): pass
    def reset(self, w, s): pass
    def compute(self, ep, *a):
        return ep[:, :, :1]

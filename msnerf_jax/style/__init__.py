"""Style: AdaIN, the 2D transfer, style vectors and blends, and feature-field stylization."""

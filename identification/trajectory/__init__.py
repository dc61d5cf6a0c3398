"""Multi-step identification through the differentiable engine: windows, Levenberg-Marquardt fits."""

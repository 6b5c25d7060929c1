"""Gaussian-process layer: backends, feature maps, diverse data selection (issue 3).

Public surface::

    from gprace.gp import make_gp, save_model, load_model, GPBackend, GPHyper
    gp = make_gp("exact", kernel="se").fit(Z, Y)       # Z (n, d), Y (n, p)
    mean, var = gp.predict(Zq)                          # latent variance, units of Y
    gp.train_inputs_                                    # Z (n, d) as given to fit (data units)
    save_model("model.h5", gp, {"feature_map": "tracking", "input_names": [...], "output_names": [...]})

Data selection lives in :mod:`gprace.gp.selection`, feature maps in :mod:`gprace.gp.features`.
"""

from gprace.gp.base import BOUNDS, GPBackend, GPHyper, SavedGP, load_model, make_gp, save_model, train_inputs

__all__ = ["BOUNDS", "GPBackend", "GPHyper", "SavedGP", "load_model", "make_gp", "save_model", "train_inputs"]

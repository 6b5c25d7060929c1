"""The report's GP section: models, posteriors over two features, datasets."""

from __future__ import annotations

from pathlib import Path

from gprace.errors import GpraceError
from gprace.gp.dataset import dataset_of
from gprace.report import figures as F
from gprace.report.collect import ITER_RE, TRIAL_RE, Found, Item, Section, path_number, table
from gprace.report.inspect import UNREADABLE, key_results, open_artifact


def gp_section(found: Found, features: tuple[str, str] | None = None, max_models: int = 4) -> Section | None:
    models = found.of("gp_model")
    datasets = found.kinds_like("dataset")
    if not models and not datasets:
        return None
    sec = Section("gp", "Gaussian processes")
    from gprace.report.single import load_gp, pick_features

    rows = []
    for p in models:
        try:
            info = key_results(open_artifact(p, "gp_model"))
        except UNREADABLE as exc:
            sec.missing.append(f"{p}: unreadable model ({exc})")
            continue
        rows.append([str(p.relative_to(found.root)), info.get("backend"), info.get("kernel"), info.get("dictionary_size"),
                     ", ".join(map(str, info.get("input_names", []))), ", ".join(map(str, info.get("output_names", [])))])
    if rows:
        sec.items.append(Item("Models", html=table(["model", "backend", "kernel", "dictionary", "inputs", "outputs"], rows)))
    if len(models) > max_models:
        sec.missing.append(f"{len(models)} models found; posterior plots drawn for {max_models} of the latest "
                           "iteration (first trial)")

    def latest(p: Path) -> tuple:
        rel = p.relative_to(found.root)
        it = path_number(rel.parent, ITER_RE)
        return (-(it if it is not None else -1), path_number(rel.parent, TRIAL_RE) or 0, str(rel))

    for p in sorted(models, key=latest)[:max_models]:
        def make(p=p):
            gp, names_in, names_out, Zd = load_gp(p)
            if Zd is None:
                raise ValueError("the model stores no dictionary points")
            try:
                i, j = pick_features(names_in, features)
            except GpraceError:  # features of another GP
                i, j = pick_features(names_in)
            return F.fig_gp_posterior(gp.predict, Zd, names_in, names_out, i, j, title=str(p.relative_to(found.root)))

        sec.add_figure(f"gp_{'_'.join(p.relative_to(found.root).with_suffix('').parts)}",
                       f"{p.relative_to(found.root)}: posterior mean and standard deviation over two features "
                       "(others at the dictionary median), dictionary points in black", make)
    for p in datasets[:2]:
        def make_d(p=p):
            ds = dataset_of(open_artifact(p), str(p))
            return F.fig_dataset(ds.Z, ds.Y, ds.input_names, ds.output_names, title=str(p.relative_to(found.root)))

        sec.add_figure(f"data_{'_'.join(p.relative_to(found.root).with_suffix('').parts)}",
                       f"{p.relative_to(found.root)}: inputs of the dataset coloured by output", make_d)
    return sec

"""Our rows next to the paper's reference numbers (supplement Tables S1-S4 and the 8-scene mean)."""

import pandas as pd

from pipeline.tables.aggregate import IRREGULAR_NOTE, ORACLE_FLAGS, Table
from pipeline.tables.labels import METRIC_KEYS, OBJECT_MEAN
from pipeline.tables.load import Runs
from pipeline.tables.paper import paper_numbers

COMPARISONS = (  # (our table, section, paper tables, our object-scene-mean rows only)
    ("table34_nerf_assets", "S3/S4", ("S3", "S4"), False),
    ("table34_nerf_assets", "8-scene mean", ("mean8",), True),
    ("table1_opt", "S1 (scene not stated)", ("S1",), True),
    ("table2_ablation", "S2 (scene not stated)", ("S2",), True),
)


def paper_comparison(tables: dict[str, Table], runs: Runs) -> Table:
    """Our rows next to the paper's (S3/S4 per scene, 8-scene mean, S1, S2): cells 'ours / paper'; a scene
    is matched by the paper scene it is or stands in for (``scene.paper_scene``)."""
    paper = paper_numbers()
    nerf_assets = paper.loc[paper["table"].isin(("S3", "S4")), "scene"].nunique()
    rows, coverage = [], []
    for name, section, sources, mean_only in COMPARISONS:
        ours = tables[name].rows
        coverage += [n for n in tables[name].notes if n.startswith(OBJECT_MEAN)] if mean_only else []
        reference = paper[paper["table"].isin(sources)]
        for _, row in ours.iterrows():
            if (row["scene"] == OBJECT_MEAN) != mean_only:
                continue
            same_scene = reference["scene"] == runs.scene(row["scene"]).paper_scene
            match = reference[(reference["method"] == row["label"]) & (mean_only | same_scene)]
            if not match.empty:
                values = {f"{m}_paper": float(match.iloc[0][m]) for m in METRIC_KEYS}
                ours_row = row.drop([f"{m}_{mark}" for m in METRIC_KEYS for mark in ("best", "tie")]).to_dict()
                ours_row["psnr_vs_nvf_n"] = 0  # the paper's numbers, not NVF's, are this table's reference
                if mean_only:  # how much of the paper's 8-scene mean ours covers, in the row itself
                    ours_row["scene"] = f"{OBJECT_MEAN} ({int(row['scene_count'])} of {nerf_assets})"
                rows.append({**ours_row, "section": section, **values})
    notes = (
        "Cells: ours (mean ± population std over seeds; the mean alone from one seed) / the paper's (supplement, "
        "mean of 3 runs).",
        "The paper ran the `paper` budget on the original assets: proxies and smaller budgets need not match.",
        *dict.fromkeys(coverage),
        *(note for flag, note in ORACLE_FLAGS if any(row.get(flag) for row in rows)),
        *((IRREGULAR_NOTE,) if any(row.get("irregular") for row in rows) else ()),
    )
    header = (f"Budget: {', '.join(sorted({r['budget'] for r in rows}))}.",) if rows else ()
    return Table("paper_comparison", "Ours vs the paper", pd.DataFrame(rows), header, notes)

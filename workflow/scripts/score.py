from pathlib import Path

from selfsense import stages

with stages.logged(snakemake.log[0]):  # noqa: F821
    stages.score(snakemake.params.dataset_dir, stages.by_trial(snakemake.input.estimates),  # noqa: F821
                 Path(snakemake.output.table3).parent)  # noqa: F821

import pandas as pd

from selfsense import stages
from selfsense.io.formats import export_estimates_mat

with stages.logged(snakemake.log[0]):  # noqa: F821
    export_estimates_mat(pd.read_parquet(snakemake.input[0]), snakemake.output[0],  # noqa: F821
                         meta={"dataset": snakemake.wildcards.dataset, "trial": snakemake.wildcards.trial})  # noqa: F821

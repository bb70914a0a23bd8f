# selfsense: raw DAQ logs -> charge -> H(q) -> A-coefficients -> estimates -> Table 3, figures, report, gap.
# Run: snakemake --cores 2            (all datasets in config.yaml)
#      snakemake --cores 2 --configfile other.yaml
# All science lives in src/selfsense; scripts in workflow/scripts are thin.
import os

from snakemake.utils import min_version, validate

min_version("8.10")


# the defaults shipped beside this Snakefile; --configfile / --config layer on top of them (partial files are fine)
configfile: os.path.join(workflow.basedir, "config.yaml")


# before the schema: YAML aliases, results_dir apart from raw_dir (symlinks resolved), solver installed
from selfsense.io.config import check_config

check_config(config, workflow.configfiles)
validate(config, "workflow/schemas/config.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/pipeline.smk"
include: "workflow/rules/ri.smk"
HAVE_GAP_RULES = os.path.exists(os.path.join(workflow.basedir, "workflow/rules/gap.smk"))


if HAVE_GAP_RULES:

    include: "workflow/rules/gap.smk"



rule all:
    input:
        expand(RESULTS + "/{dataset}/report.html", dataset=DATASETS),
    default_target: True

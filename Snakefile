# selfsense: raw DAQ logs -> charge -> H(q) -> A-coefficients -> estimates -> Table 3, figures, report, gap.
# Run: snakemake --cores 2            (all datasets in config.yaml)
#      snakemake --cores 2 --configfile other.yaml
#      snakemake --report report.zip   (Snakemake's report: every table and figure with its caption)
# Also usable as a Snakemake module from another workflow (docs/scale_out.md). All science lives in src/selfsense.
import os

from snakemake.utils import min_version, validate

min_version("8.10")


# the defaults shipped beside this Snakefile; --configfile / --config layer on top of them (partial files are fine)
configfile: os.path.join(workflow.basedir, "config.yaml")


# before the schema: YAML aliases, results_dir apart from raw_dir (symlinks resolved), solver installed
from selfsense.io.config import check_config

check_config(config, workflow.configfiles)
validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/pipeline.smk"
include: "workflow/rules/gap.smk"
include: "workflow/rules/ri.smk"
include: "workflow/rules/devices.smk"


rule all:
    default_target: True
    input:
        expand(res("{dataset}", "report.html"), dataset=DATASETS),

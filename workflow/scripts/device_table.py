import json
from pathlib import Path

from selfsense import stages
from selfsense.devices import write_tables
from selfsense.process import end_now

with stages.logged(snakemake.log[0]):  # noqa: F821
    recs = [json.loads(Path(p).read_text()) for p in snakemake.input]  # noqa: F821
    write_tables(recs, Path(snakemake.output.md).parent)  # noqa: F821
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for

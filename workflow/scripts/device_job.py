from selfsense import stages
from selfsense.devices import run_device, write_record
from selfsense.process import end_now

with stages.logged(snakemake.log[0]):  # noqa: F821
    family, preset, seed = snakemake.wildcards.family, snakemake.wildcards.preset, int(snakemake.wildcards.seed)  # noqa: F821
    rec = run_device(family, preset, seed, snakemake.params.config)  # noqa: F821
    write_record(rec, snakemake.output[0])  # noqa: F821
    print(f"{family} {preset} {seed}: displacement {rec['displacement_pct']:.2f} %, force {rec['force_pct']:.2f} %")
end_now()  # outputs written and closed: no interpreter teardown for Snakemake to wait for

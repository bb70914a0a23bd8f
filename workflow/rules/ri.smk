# The third seed (002_7d89b7147aad52e4.txt) as pipeline targets, not part of the default run:
#     snakemake --cores 2 ri_tables
# writes the RI paper's Table 2-style validation (RMS / max error at 50-500 Hz on the virtual single stack of
# selfsense.hysteresis.ri_dynamics) and the RI vs modified-PI comparison on the SLAC one-sided magnet data.


rule ri_validation_table:
    output:
        RESULTS + "/ri/table2_validation.md",
    log:
        RESULTS + "/ri/logs/ri_validation_table.log",
    benchmark:
        RESULTS + "/ri/benchmarks/ri_validation_table.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    shell:
        "{PYTHON} -m selfsense ri validate-table --out {output} > {log} 2>&1"


rule ri_compare_slac:
    output:
        RESULTS + "/ri/slac_comparison.md",
    params:
        data=lambda w: slac_data_dir(),
    log:
        RESULTS + "/ri/logs/ri_compare_slac.log",
    benchmark:
        RESULTS + "/ri/benchmarks/ri_compare_slac.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    shell:
        "{PYTHON} -m selfsense ri compare-slac --data {params.data} --out {output} > {log} 2>&1"


rule ri_tables:
    input:
        RESULTS + "/ri/table2_validation.md",
        RESULTS + "/ri/slac_comparison.md",

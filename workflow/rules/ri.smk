# The third seed (002_7d89b7147aad52e4.txt) as pipeline targets, not part of the default run:
#     snakemake --cores 2 ri_tables --config slac_data_dir=DIR
# writes the RI paper's Table 2-style validation (RMS / max error at 50-500 Hz on the virtual single stack of
# selfsense.hysteresis.ri_dynamics) and the RI vs modified-PI comparison on the SLAC one-sided magnet data
# (folder DIR with strdat.ru3/strdat.ru4; not bundled with the project).


rule ri_validation_table:
    output:
        report(
            res("ri", "table2_validation.md"),
            caption="../report/ri_table2.rst",
            category="RI model",
        ),
    log:
        res("ri", "logs", "ri_validation_table.log"),
    benchmark:
        res("ri", "benchmarks", "ri_validation_table.tsv")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    run:
        ri_main(["validate-table", "--out", output[0]], log[0])


rule ri_compare_slac:
    output:
        report(
            res("ri", "slac_comparison.md"),
            caption="../report/ri_slac.rst",
            category="RI model",
        ),
    log:
        res("ri", "logs", "ri_compare_slac.log"),
    benchmark:
        res("ri", "benchmarks", "ri_compare_slac.tsv")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        data=slac_data_dir,
    run:
        ri_main(["compare-slac", "--data", params.data, "--out", output[0]], log[0])


rule ri_tables:
    input:
        res("ri", "table2_validation.md"),
        res("ri", "slac_comparison.md"),

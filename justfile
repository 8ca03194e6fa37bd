# Convenience recipes; each is a plain cargo command that works without `just` too.

# The viewer on the bundled demo (a window, or a PNG without a display).
demo *ARGS:
    cargo run --release -p vds-view -- {{ARGS}}

# The whole test suite (what CI runs after fmt and clippy).
test:
    cargo test --workspace --release

# Everything CI checks.
ci:
    bash .ci/run

# Generate CAD-like scenes and print build throughput and memory (docs/benchmarks.md).
bench:
    cargo run --release -p vds-bench

# The runtime along camera paths, and its fidelity against simplify_sloppy (docs/benchmarks.md).
bench-cut:
    cargo run --release -p vds-bench -- cut

# Export the cut of a .vdt file from the default camera: just cut out/bunny.vdt out/cut.obj 1
cut FILE OUT THRESHOLD:
    cargo run --release -p vds-runtime --bin vds-cut -- {{FILE}} -o {{OUT}} --threshold {{THRESHOLD}}

# Generate a CAD-like scene: just gen 1M out/cad-1M.ply
gen COUNT OUT:
    cargo run --release -p vds-gen -- --triangles {{COUNT}} --out {{OUT}}

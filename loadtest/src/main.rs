//! `dynaserve-loadtest`: see the crate documentation and `loadtest/README.md`.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() {
    // SAFETY: first statement of main; no other thread exists yet. The in-process baseline
    // must run candle with the same thread settings as the server binary.
    unsafe { dynaserve_model::configure_compute(None) };
    dynaserve_model::keep_freed_memory();
    match dynaserve_loadtest::cli::main() {
        Ok(0) => {}
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}

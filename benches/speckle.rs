//! `cargo bench`: the same figures as `lightpath bench` (reference scene of issue #2).

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    match lightpath::app::bench::run(quick) {
        Ok(s) => println!("{s}"),
        Err(e) => {
            eprintln!("bench failed: {e}");
            std::process::exit(1);
        }
    }
}

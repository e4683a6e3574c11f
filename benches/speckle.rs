//! `cargo bench`: the same figures as `lightpath bench` (reference scene (`lightpath bench`)).

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

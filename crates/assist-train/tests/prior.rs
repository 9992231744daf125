//! The built-in background priors measured on desk's background ground truth: both fills
//! must beat leaving the objects in place, and the default (push–pull) must be the better
//! of the two — if a change to the exemplar fill makes it win, this says to switch.

use assist_data::Split;
use assist_train::PriorKind;
use assist_train::evaluate_priors;

#[test]
fn default_prior_is_the_better_fill_on_desk() {
    let Some(root) =
        assist_testkit::shared_dataset("default_prior_is_the_better_fill_on_desk", "desk")
    else {
        return;
    };
    let ds = assist_data::load(&root, &Default::default()).unwrap();
    let kinds = [PriorKind::None, PriorKind::PushPull, PriorKind::Exemplar];
    let r = evaluate_priors(&ds, Some(Split::Test), &kinds, |_, _| {}).unwrap();
    let psnr: Vec<f64> = r.scores.iter().map(|s| s.occluded_psnr).collect();
    eprintln!(
        "desk, {} views, {} pixels under objects: objects left {:.2} dB, push-pull {:.2} dB, exemplar {:.2} dB",
        r.views, r.occluded_pixels, psnr[0], psnr[1], psnr[2]
    );
    assert_eq!(r.views, 20);
    assert!(
        psnr[1] > psnr[0] + 3.0 && psnr[2] > psnr[0] + 1.0,
        "{psnr:?}"
    );
    assert!(
        psnr[1] >= psnr[2],
        "exemplar now beats push-pull: make it the default ({psnr:?})"
    );
}

#[test]
fn prior_needs_background_truth() {
    let Some(root) = assist_testkit::shared_dataset("prior_needs_background_truth", "lego_400")
    else {
        return;
    };
    let ds = assist_data::load(&root, &Default::default()).unwrap();
    let e = evaluate_priors(&ds, None, &[PriorKind::PushPull], |_, _| {}).unwrap_err();
    assert!(e.to_string().contains("background"), "{e}");
}

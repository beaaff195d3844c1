// Coherent queries (TraversalFront): over whole trajectories, every step's contacts equal those of a query from the
// root, bit for bit and in the same order, while far fewer lookups are made when little moves. And what a query
// against a partner's function evaluates.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstring>
#include <iostream>

#include "analytic_sphere.h"
#include "baked_bunny.h"
#include "traversal/function_query.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {
namespace {

using test::BakedBunny;

Pose pose_at(const Eigen::Vector3d& axis, double angle, const Eigen::Vector3d& translation) {
  Pose p;
  p.rotation = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  p.translation = translation;
  return p;
}

// Contacts compared field by field, bitwise: the coherent query must not change a single bit.
void expect_identical(const ContactSet& fresh, const ContactSet& coherent, size_t step) {
  ASSERT_EQ(fresh.contacts.size(), coherent.contacts.size()) << "step " << step;
  for (size_t i = 0; i < fresh.contacts.size(); ++i) {
    const Contact &a = fresh.contacts[i], &b = coherent.contacts[i];
    ASSERT_EQ(a.point_index, b.point_index) << "step " << step << " contact " << i;
    ASSERT_EQ(a.point_of_b, b.point_of_b);
    ASSERT_EQ(std::memcmp(&a.depth, &b.depth, sizeof a.depth), 0) << a.depth << " vs " << b.depth;
    ASSERT_EQ(a.point, b.point);
    ASSERT_EQ(a.normal, b.normal);
    ASSERT_EQ(a.exact, b.exact);
  }
}

struct Lookups {
  size_t fresh = 0, coherent = 0, contacts = 0;
  size_t unordered = 0;  // steps after which A's front was left unordered (large motion: a pass each query)
};

// Runs `steps` poses of A against the fixed B through both queries; returns the lookups each made.
template <class PoseAt>
Lookups run_trajectory(const CollisionObject& a, const CollisionObject& b, QueryOptions options, size_t steps,
                       PoseAt&& pose_at_step) {
  QueryScratch scratch;
  QueryState state;
  ContactSet fresh, coherent;
  Lookups lookups;
  const Pose pose_b;
  for (size_t s = 0; s < steps; ++s) {
    const Pose pa = pose_at_step(s);
    fresh.clear();
    coherent.clear();
    query_contacts(a, pa, b, pose_b, options, fresh, scratch);
    query_contacts(a, pa, b, pose_b, options, coherent, scratch, state);
    expect_identical(fresh, coherent, s);
    if (::testing::Test::HasFatalFailure()) return lookups;
    lookups.fresh += fresh.stats.nodes_visited + fresh.stats.points_tested;
    lookups.coherent += coherent.stats.nodes_visited + coherent.stats.points_tested;
    lookups.contacts += fresh.contacts.size();
    lookups.unordered += state.a_in_b.state().ordered ? 0 : 1;
  }
  return lookups;
}

TEST(Coherence, BunnyApproachingSlidingAndLeavingABunnyGivesTheSameContacts) {
  // A 1 kHz trajectory: A comes in along x, overlaps up to ~4 voxels while turning and sliding, and leaves.
  const BakedBunny& bunny = BakedBunny::get();
  const double h = bunny.h;
  for (const QueryDirection direction :
       {QueryDirection::APointsInB, QueryDirection::BPointsInA, QueryDirection::Both}) {
    QueryOptions options;
    options.direction = direction;
    options.proximity = 0.5 * h;
    const size_t steps = 600;
    const Lookups l = run_trajectory(*bunny.object, *bunny.object, options, steps, [&](size_t s) {
      const double t = double(s) / double(steps);
      const double gap = 0.97 - 0.12 * std::sin(3.14159265358979 * t);  // in, deepest at the middle, out
      return pose_at(Eigen::Vector3d(0.2, 1, 0.1), 0.3 * t, Eigen::Vector3d(gap, 0.05 * t, -0.02 * t));
    });
    std::cout << "[ figures  ] direction " << int(direction) << ": " << l.contacts << " contacts over " << steps
              << " steps; lookups from the root " << l.fresh << ", coherent " << l.coherent << " ("
              << double(l.fresh) / double(std::max<size_t>(l.coherent, 1)) << "x fewer)\n";
    EXPECT_GT(l.contacts, 1000u);
    EXPECT_LT(l.coherent, l.fresh);
  }
}

TEST(Coherence, ARockingBodyThatIsKnockedAwayAndSettlesGivesTheSameContacts) {
  // A resting body rocks about its pose (what a solver does), is knocked into a fast turn and slide, then rocks
  // about a new pose: the front goes from the heap to one pass a query and back, and never changes a bit.
  const BakedBunny& bunny = BakedBunny::get();
  const double h = bunny.h;
  QueryOptions options;
  options.direction = QueryDirection::Both;
  options.proximity = 0.25 * h;
  const size_t steps = 900;
  const Lookups l = run_trajectory(*bunny.object, *bunny.object, options, steps, [&](size_t s) {
    const double t = double(s);
    const double rock = 2e-3 * std::sin(0.7 * t) * std::exp(-t / 200.0);  // radians, decaying
    const double knocked = s < 300 ? 0.0 : std::min(1.0, double(s - 300) / 100.0);
    const double angle = rock + 0.25 * knocked;
    const Eigen::Vector3d slide(0.86 + 0.02 * knocked, 0.03 * knocked, 0.2 * h * std::sin(0.3 * t) * 0.01);
    return pose_at(Eigen::Vector3d(0.1, 1, 0.3), angle, slide);
  });
  std::cout << "[ figures  ] rocking, knocked, settling: " << l.contacts << " contacts; lookups from the root "
            << l.fresh << ", coherent " << l.coherent << "; " << l.unordered << " of " << steps
            << " steps left the front unordered\n";
  EXPECT_GT(l.contacts, 1000u);
  EXPECT_LT(l.coherent, l.fresh);
  // Both ways of keeping the front were taken.
  EXPECT_GT(l.unordered, 0u);
  EXPECT_LT(l.unordered, steps);
}

TEST(Coherence, ABodyTurningInsideAnotherGivesTheSameContactsRoundAfterRound) {
  // Deep overlap, turning and swaying, the same path four times with one state: a point revisited on its own was
  // once sampled without its sphere's gate, and a distance interpolated a little below the bound of the true
  // distance made a contact the walk from the root never reaches (7 of 2,000 steps on two other shapes).
  const BakedBunny& bunny = BakedBunny::get();
  const double h = bunny.h;
  QueryOptions options;
  options.direction = QueryDirection::APointsInB;
  const size_t steps = 400, rounds = 4;
  const Lookups l = run_trajectory(*bunny.object, *bunny.object, options, steps * rounds, [&](size_t s) {
    const double i = double(s % steps);
    return pose_at(Eigen::Vector3d::UnitZ(), 0.05 * i,
                   Eigen::Vector3d(20 * h * std::sin(0.1 * i), 10 * h * std::cos(0.13 * i), 0));
  });
  std::cout << "[ figures  ] turning inside: " << l.contacts << " contacts; lookups from the root " << l.fresh
            << ", coherent " << l.coherent << "; " << l.unordered << " of " << steps * rounds
            << " steps left the front unordered\n";
  EXPECT_GT(l.contacts, 100000u);
  EXPECT_LT(l.unordered, steps * rounds);  // the front was kept and revisited, not only rebuilt
}

TEST(Coherence, TricubicQueriesGiveTheSameContactsWhateverTheReadingBefore) {
  // The tricubic reading steps where it gives way to trilinear, so its sampled points keep no bound and are looked
  // up again each query. And one state queried with either reading in turn gives each query's own contacts (the
  // front starts afresh at a change: its bounds are of the other reading's samples).
  const BakedBunny& bunny = BakedBunny::get();
  const double h = bunny.h;
  const size_t steps = 600;
  const auto path = [&](size_t s) {
    const double t = double(s % steps) / double(steps);
    const double gap = 0.97 - 0.12 * std::sin(3.14159265358979 * t);
    return pose_at(Eigen::Vector3d(0.2, 1, 0.1), 0.3 * t, Eigen::Vector3d(gap, 0.05 * t, -0.02 * t));
  };
  QueryOptions options;
  options.direction = QueryDirection::APointsInB;
  options.proximity = 0.5 * h;
  options.interpolation = Interpolation::Tricubic;
  const Lookups l = run_trajectory(*bunny.object, *bunny.object, options, steps, path);
  EXPECT_GT(l.contacts, 1000u);
  EXPECT_LT(l.coherent, l.fresh);

  QueryScratch scratch;
  QueryState state;
  ContactSet fresh, coherent;
  size_t differing = 0;
  for (size_t s = 0; s < 200; ++s) {
    QueryOptions o = options;
    o.interpolation = (s / 3) % 2 ? Interpolation::Tricubic : Interpolation::Trilinear;
    const Pose pa = path(200 + s);
    fresh.clear();
    coherent.clear();
    query_contacts(*bunny.object, pa, *bunny.object, Pose{}, o, fresh, scratch);
    query_contacts(*bunny.object, pa, *bunny.object, Pose{}, o, coherent, scratch, state);
    expect_identical(fresh, coherent, s);
    if (HasFatalFailure()) return;
    // The two readings differ at this overlap (else the test would prove nothing about the change).
    ContactSet other;
    QueryOptions flipped = o;
    flipped.interpolation =
        o.interpolation == Interpolation::Tricubic ? Interpolation::Trilinear : Interpolation::Tricubic;
    query_contacts(*bunny.object, pa, *bunny.object, Pose{}, flipped, other, scratch);
    differing += other.contacts.size() != fresh.contacts.size() ||
                 (!fresh.contacts.empty() && other.contacts[0].depth != fresh.contacts[0].depth);
  }
  EXPECT_GT(differing, 100u);
}

TEST(Coherence, ABodyAtRestLooksUpOnlyItsContacts) {
  // Resting contact: the same pose step after step. After the first step only the points in contact (and those
  // within reach) are looked up again.
  const BakedBunny& bunny = BakedBunny::get();
  QueryOptions options;
  options.direction = QueryDirection::APointsInB;
  const Pose rest = pose_at(Eigen::Vector3d::UnitY(), 0.0, Eigen::Vector3d(0.85, 0, 0));
  const Lookups l = run_trajectory(*bunny.object, *bunny.object, options, 100, [&](size_t) { return rest; });
  std::cout << "[ figures  ] at rest: lookups from the root " << l.fresh / 100 << " a step, coherent "
            << l.coherent / 100 << " a step (" << l.contacts / 100 << " contacts)\n";
  EXPECT_GT(l.contacts, 100u);
  // The first step from the root, then only the contacts: a bound and a distance for each contact a step.
  EXPECT_LT(l.coherent, 2 * l.contacts + l.fresh / 100 + 100);
}

TEST(Coherence, AnAnalyticPartnerMovingWithTheShellChangesNothing) {
  // A plane (a function in world coordinates) and the bunny moving together: the relative pose is constant, so
  // the front is kept whole although both move in the world; contacts match the query from the root.
  const BakedBunny& bunny = BakedBunny::get();
  QueryOptions options;
  options.proximity = 0.2 * bunny.h;
  QueryScratch scratch;
  TraversalFront front;
  ContactSet fresh, coherent;
  size_t fresh_lookups = 0, coherent_lookups = 0;
  for (int s = 0; s < 200; ++s) {
    const Pose partner = pose_at(Eigen::Vector3d(1, 1, 0), 0.002 * s, Eigen::Vector3d(0.001 * s, 0.0005 * s, 0));
    Pose shell = partner;  // the bunny 0.49 m above the plane's origin, in the plane's frame, 2 voxels deep
    shell.translation = partner.rotation * Eigen::Vector3d(0, 0.49 - 2 * bunny.h, 0) + partner.translation;
    const Eigen::Vector3f n = (partner.rotation * Eigen::Vector3d::UnitY()).cast<float>();
    const float c = n.dot(partner.translation.cast<float>());
    auto plane = [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
      outward = n;
      return n.dot(x) - c;
    };
    fresh.clear();
    coherent.clear();
    query_against_function(*bunny.object, shell, plane, options, fresh, scratch);
    query_against_function(*bunny.object, shell, partner, plane, options, coherent, scratch, front);
    expect_identical(fresh, coherent, size_t(s));
    if (HasFatalFailure()) return;
    // Nothing moves relative to the plane: after the first step only the points in contact are looked up.
    if (s > 0) {
      EXPECT_LE(coherent.stats.nodes_visited + coherent.stats.points_tested, coherent.contacts.size() + 16);
    }
    fresh_lookups += fresh.stats.nodes_visited + fresh.stats.points_tested;
    coherent_lookups += coherent.stats.nodes_visited + coherent.stats.points_tested;
  }
  EXPECT_GT(fresh.contacts.size(), 100u);
  std::cout << "[ figures  ] lookups from the root " << fresh_lookups / 200 << " a step, coherent "
            << coherent_lookups / 200 << " (" << fresh.contacts.size() << " contacts)\n";
}

TEST(Coherence, QueriesWithABudgetStartAfresh) {
  // A point budget cuts the traversal: such a query cannot keep a front, and the next full one starts afresh.
  const BakedBunny& bunny = BakedBunny::get();
  QueryScratch scratch;
  QueryState state;
  ContactSet fresh, coherent;
  const Pose pa = pose_at(Eigen::Vector3d::UnitZ(), 0.2, Eigen::Vector3d(0.96, 0, 0));
  QueryOptions full, budget;
  full.direction = budget.direction = QueryDirection::APointsInB;
  budget.point_budget = 800;
  for (const QueryOptions* o : {&full, &budget, &full}) {
    fresh.clear();
    coherent.clear();
    query_contacts(*bunny.object, pa, *bunny.object, Pose{}, *o, fresh, scratch);
    query_contacts(*bunny.object, pa, *bunny.object, Pose{}, *o, coherent, scratch, state);
    expect_identical(fresh, coherent, 0);
    EXPECT_EQ(state.a_in_b.state().valid, o == &full);
  }
}

TEST(Coherence, AStateQueriedForAnotherPairStartsAfresh) {
  // One QueryState carried from pair to pair (the header says one per pair; it once read the old tree's node
  // numbers in the new tree, or kept another field's bounds): each query as a fresh one, bit for bit.
  const BakedBunny& bunny = BakedBunny::get();
  auto loaded = CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, 0.3, 0.02, 3000, 4}));
  ASSERT_TRUE(loaded);
  const CollisionObject& ball = *loaded.value();
  QueryScratch scratch;
  QueryState state;
  QueryOptions options;
  options.direction = QueryDirection::APointsInB;
  const Pose near = pose_at(Eigen::Vector3d::UnitZ(), 0.2, Eigen::Vector3d(0.7, 0.05, 0));
  const Pose inside = pose_at(Eigen::Vector3d::UnitY(), 0.3, Eigen::Vector3d(0.1, 0.1, 0.05));
  struct Step {
    const CollisionObject* a;
    const CollisionObject* b;
    Pose pose_a;
  };
  const Step steps[] = {{bunny.object.get(), bunny.object.get(), near},
                        {bunny.object.get(), bunny.object.get(), near},
                        {&ball, bunny.object.get(), inside},
                        {bunny.object.get(), &ball, inside},
                        {bunny.object.get(), bunny.object.get(), near}};
  for (size_t s = 0; s < std::size(steps); ++s) {
    ContactSet fresh, coherent;
    query_contacts(*steps[s].a, steps[s].pose_a, *steps[s].b, Pose{}, options, fresh, scratch);
    query_contacts(*steps[s].a, steps[s].pose_a, *steps[s].b, Pose{}, options, coherent, scratch, state);
    EXPECT_FALSE(fresh.contacts.empty()) << "step " << s;
    expect_identical(fresh, coherent, s);
  }
}

TEST(Coherence, AnObjectLoadedWhereAnotherWasStartsItsPairAfresh) {
  // A reload: an object assigned over another at the same address, with as many points and a grid no larger (so
  // its arrays keep their storage too). The state knows its pair by the objects' ids: each query as a fresh one.
  const BakedBunny& bunny = BakedBunny::get();
  auto first = CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, 0.3, 0.02, 3000, 4}));
  auto second = CollisionObject::from_asset(test::make_sphere_asset({{0.04, 0.03, 0}, 0.26, 0.02, 3000, 4}));
  ASSERT_TRUE(first && second);
  ASSERT_EQ(first.value()->point_tree().size(), second.value()->point_tree().size());
  EXPECT_NE(first.value()->id(), second.value()->id());
  const Pose inside = pose_at(Eigen::Vector3d::UnitY(), 0.3, Eigen::Vector3d(0.1, 0.1, 0.05));
  for (const QueryDirection direction : {QueryDirection::APointsInB, QueryDirection::BPointsInA}) {
    CollisionObject ball = *first.value();
    QueryScratch scratch;
    QueryState state;
    QueryOptions options;
    options.direction = direction;
    for (int reload = 0; reload < 2; ++reload) {
      if (reload == 1) ball = *second.value();
      for (int repeat = 0; repeat < 2; ++repeat) {
        ContactSet fresh, coherent;
        query_contacts(*bunny.object, inside, ball, Pose{}, options, fresh, scratch);
        query_contacts(*bunny.object, inside, ball, Pose{}, options, coherent, scratch, state);
        EXPECT_FALSE(fresh.contacts.empty()) << "reload " << reload;
        expect_identical(fresh, coherent, size_t(2 * reload + repeat));
      }
    }
  }
}

// A query against a partner's function evaluates it once a tested point: the contact keeps the outward normal of
// the sample that gave its depth. A cut level's sphere, sampled at its centre, takes its normal at its point.
TEST(FunctionQuery, AContactKeepsItsSamplesNormalAndACutSphereTakesItsPoints) {
  const BakedBunny& bunny = BakedBunny::get();
  Pose shell;
  shell.translation = Eigen::Vector3d(0, 0.49 - 2 * bunny.h, 0);  // its lowest points about 2 voxels into the sphere
  const Eigen::Vector3f centre(0.0f, -2.0f, 0.0f);
  const float radius = 2.0f;
  size_t calls = 0;
  auto sphere = [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    ++calls;
    outward = (x - centre).normalized();
    return (x - centre).norm() - radius;
  };
  auto bound = [&](const Eigen::Vector3f& x) { return (x - centre).norm() - radius; };
  const auto outward_at = [&](const Eigen::Vector3d& p) -> Eigen::Vector3d {
    return (p.cast<float>() - centre).normalized().cast<double>();
  };
  QueryOptions options;
  QueryScratch scratch;
  ContactSet out;
  query_against_function(*bunny.object, shell, sphere, bound, options, out, scratch);
  ASSERT_GT(out.contacts.size(), 50u);
  EXPECT_EQ(calls, out.stats.points_tested);  // none again for a contact
  for (const Contact& c : out.contacts) ASSERT_LT((c.normal - outward_at(c.point)).norm(), 1e-5) << c.point_index;
  options.max_level = 3;
  options.cut_level = CutLevel::Spheres;
  out.clear();
  query_against_function(*bunny.object, shell, sphere, bound, options, out, scratch);
  size_t spheres = 0;
  for (const Contact& c : out.contacts) {
    if (c.exact) continue;
    ++spheres;
    ASSERT_LT((c.normal - outward_at(c.point)).norm(), 1e-6) << c.point_index;
  }
  EXPECT_GT(spheres, 0u);
}

}  // namespace
}  // namespace voxfmt::runtime

// The CGAL 5.5 vptr report of tests/sanitizer/ubsan.supp without any cityforge code (CGAL issue #9140).
// g++ -std=c++20 -O1 -fsanitize=address,undefined -fno-sanitize-recover=undefined -frounding-math cgal_vptr_repro.cc -lgmp -lmpfr
// ./a.out reports in Arrangement_2_iterators.h; UBSAN_OPTIONS=suppressions=ubsan.supp ./a.out runs clean.
#include <CGAL/Arrangement_2.h>
#include <CGAL/Arr_segment_traits_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <iostream>
using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Traits = CGAL::Arr_segment_traits_2<Kernel>;
using Arrangement = CGAL::Arrangement_2<Traits>;
int main() {
  Arrangement arr;
  std::cerr << "unbounded: " << arr.unbounded_face()->is_unbounded() << "\n";
  CGAL::insert(arr, Traits::Segment_2(Kernel::Point_2(0,0), Kernel::Point_2(1,1)));
  CGAL::insert(arr, Traits::Segment_2(Kernel::Point_2(0,1), Kernel::Point_2(1,0)));
  std::size_t n = 0;
  for (auto f = arr.faces_begin(); f != arr.faces_end(); ++f) ++n;
  std::cerr << "faces " << n << "\n";
}
